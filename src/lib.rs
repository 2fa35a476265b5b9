pub use twistopt_solver as solver;
