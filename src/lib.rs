//! twistopt: design optimisation of soft twisting pneumatic actuators.
//!
//! * [`geometry`]: the parametric actuator geometry (GEOMETRY.md), closed forms and volumes;
//! * [`meshing`]: structured hexahedral meshes of the wall (Hex8/Hex20/Hex27, full or 120° sector)
//!   with named node/face sets, quality report and shape derivatives;
//! * [`export`]: VTU/PVD, STL and INP writers; [`calculix`]: CalculiX decks of the scenes, runs, results;
//! * [`problem`]: TOML problem files; [`evaluate`]: run a problem's scenes and write its outputs;
//! * [`plot`]: PNG/SVG line plots with an embedded font;
//! * [`sweep`]: resumable, shardable grid sweeps (the letter's Table I), Fig.-5 maps, optimiser check;
//! * [`cli`]: the command-line interface.
pub use twistopt_solver as solver;

pub mod calculix;
pub mod cli;
pub mod evaluate;
pub mod export;
pub mod geometry;
pub mod gradient;
pub mod meshing;
pub mod optimise;
pub mod plot;
pub mod problem;
pub mod rom;
pub mod scene;
pub mod sweep;

/// Keep freed memory for reuse instead of handing it back to the system (glibc only; elsewhere
/// a no-op). A reduced-model design allocates and frees buffers of a few MB at every path
/// setup and evaluation (the design's rotated basis, the sampled points' ∂F/∂z, the cavity's
/// rows): with glibc's defaults each comes from a fresh mmap or a re-grown heap, and its pages
/// are faulted in and zeroed again every time. Measured: a reduced path's setup 21 → 11 ms
/// (bench `rom_evaluation`'s design, fastest of 100); whole sweep runs moved within the machine's
/// noise. Called first by the `twistopt` binary
/// and the benchmarks; the thresholds are 32 MB (glibc's largest mmap threshold) and 64 MB.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; called before any other thread starts
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
    }
}
