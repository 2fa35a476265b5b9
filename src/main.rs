use clap::Parser;

fn main() {
    let cli = twistopt::cli::Cli::parse();
    if let Err(e) = twistopt::cli::run(cli) {
        // one line, naming the offending field
        let msg = format!("{e:#}").replace('\n', " ");
        eprintln!("error: {msg}");
        std::process::exit(1);
    }
}
