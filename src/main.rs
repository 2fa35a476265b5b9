use clap::Parser;

fn main() {
    twistopt::tune_allocator();
    let cli = match twistopt::cli::Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand) {
                e.exit();
            }
            // usage errors on one line (the full usage is in --help)
            let text = e.to_string();
            let msg: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more information")).collect();
            eprintln!("{} (see --help)", msg.join(" "));
            std::process::exit(2);
        }
    };
    if let Err(e) = twistopt::cli::run(cli) {
        // one line, naming the offending field
        let msg = format!("{e:#}").replace('\n', " ");
        eprintln!("error: {msg}");
        std::process::exit(1);
    }
}
