//! Reader for the CalculiX `.dat` file (`*NODE PRINT` blocks) and the run log.
//!
//! A block is a header line such as
//! `displacements (vx,vy,vz) for set REFNODE and time  0.1000000E+01`
//! followed by a blank line and one line per node: `node v1 v2 v3`.

use anyhow::{bail, Result};

/// One printed block.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// the quantity as ccx names it: `displacements`, `forces`, …
    pub what: String,
    /// node set name (upper case, as ccx prints it)
    pub set: String,
    /// total time
    pub time: f64,
    /// (1-based node number, three components)
    pub values: Vec<(usize, [f64; 3])>,
}

/// Parse every `… for set NAME and time T` block with three components per node.
pub fn parse_dat(text: &str) -> Result<Vec<Block>> {
    let mut out: Vec<Block> = Vec::new();
    let mut cur: Option<Block> = None;
    for (lineno, line) in text.lines().enumerate() {
        let t = line.trim();
        if let Some((head, rest)) = t.split_once(" for set ") {
            if let Some(b) = cur.take() {
                out.push(b);
            }
            let what = head.split_whitespace().next().unwrap_or("").to_string();
            let Some((set, time)) = rest.split_once(" and time") else {
                bail!("ccx .dat line {}: cannot read the header '{t}'", lineno + 1);
            };
            let time: f64 = match time.trim().parse() {
                Ok(v) => v,
                Err(_) => bail!("ccx .dat line {}: cannot read the time in '{t}'", lineno + 1),
            };
            cur = Some(Block { what, set: set.trim().to_uppercase(), time, values: Vec::new() });
            continue;
        }
        if t.is_empty() {
            continue;
        }
        let Some(b) = cur.as_mut() else { continue };
        let f: Vec<&str> = t.split_whitespace().collect();
        if f.len() < 4 {
            // a block of another shape (e.g. totals or element output): stop this block
            out.push(cur.take().unwrap());
            continue;
        }
        let Ok(node) = f[0].parse::<usize>() else {
            out.push(cur.take().unwrap());
            continue;
        };
        let mut v = [0.0; 3];
        for i in 0..3 {
            v[i] = match f[1 + i].parse::<f64>() {
                Ok(x) => x,
                Err(_) => bail!("ccx .dat line {}: cannot read a number in '{t}'", lineno + 1),
            };
        }
        b.values.push((node, v));
    }
    if let Some(b) = cur.take() {
        out.push(b);
    }
    Ok(out)
}

/// The number of equations ccx reports in its log ("number of equations" followed by the number).
pub fn equations(log: &str) -> Option<usize> {
    let mut lines = log.lines();
    while let Some(l) = lines.next() {
        if l.trim() == "number of equations" {
            return lines.next().and_then(|n| n.trim().parse().ok());
        }
    }
    None
}

/// The number of converged increments in the log: ccx ends each with a line starting with
/// "convergence" ("no convergence" ends an iteration that did not converge).
pub fn increments(log: &str) -> usize {
    log.lines().filter(|l| l.trim_start().starts_with("convergence")).count()
}

/// The number of Newton iterations in the log (lines "iteration N"), cut-back attempts included.
pub fn iterations(log: &str) -> usize {
    log.lines().filter(|l| l.trim_start().starts_with("iteration ")).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_blocks() {
        let text = "\n                        S T E P       1\n\n\n displacements (vx,vy,vz) for set REFNODE and time  0.5000000E+00\n\n      2001  1.000000E-02 -2.000000E-03  3.500000E-01\n\n forces (fx,fy,fz) for set ROTNODE and time  0.1000000E+01\n\n      2002 -1.0E+00  2.0E+00 -4.567000E+01\n      2003  0  0  0\n";
        let b = parse_dat(text).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0].what, "displacements");
        assert_eq!(b[0].set, "REFNODE");
        assert_eq!(b[0].time, 0.5);
        assert_eq!(b[0].values, vec![(2001, [0.01, -0.002, 0.35])]);
        assert_eq!(b[1].what, "forces");
        assert_eq!(b[1].values.len(), 2);
        assert_eq!(b[1].values[0].1[2], -45.67);
        assert!(parse_dat(" displacements (vx,vy,vz) for set A and time  x\n").is_err());
        assert_eq!(equations("foo\n number of equations\n 1234\n"), Some(1234));
        let log = " iteration 1\n no convergence\n iteration 2\n convergence\n iteration 1\n convergence; the increment size is increased\n";
        assert_eq!(increments(log), 2);
        assert_eq!(iterations(log), 3);
    }
}
