//! twistopt-solver: a finite-strain, nearly incompressible hyperelastic FE core.
//!
//! It knows nothing of actuators or optimisation: meshes, elements, materials, constraints
//! (fixed/prescribed DOFs, rigid bodies, cyclic symmetry), follower pressure on closed cavities,
//! sparse assembly, Newton with line search, adaptive load stepping and adjoint sensitivities.

pub mod adjoint;
pub mod contact;
pub mod continuation;
pub mod dofmap;
pub mod element;
pub mod fpenv;
pub mod integrity;
pub mod material;
pub mod mesh;
pub mod meshgen;
pub mod model;
pub mod rom;
pub mod scalar;
pub mod shape;
pub mod solve;
pub mod surface;
pub mod verify;
