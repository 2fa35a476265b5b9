//! twistopt: design optimisation of soft twisting pneumatic actuators.
//!
//! * [`geometry`]: the parametric actuator geometry (GEOMETRY.md), closed forms and volumes;
//! * [`meshing`]: structured hexahedral meshes of the wall (Hex8/Hex20/Hex27, full or 120° sector)
//!   with named node/face sets, quality report and shape derivatives;
//! * [`export`]: VTU/PVD, STL and INP writers;
//! * [`cli`]: the command-line interface.
pub use twistopt_solver as solver;

pub mod cli;
pub mod export;
pub mod geometry;
pub mod meshing;
pub mod scene;
