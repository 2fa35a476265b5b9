//! File exports: VTU/PVD (ParaView), STL (closed surfaces) and INP (CalculiX/Abaqus).

pub mod inp;
pub mod stl;
pub mod vtu;

pub use inp::write_inp;
pub use stl::{cavity_surface, outer_surface, write_stl_binary, ClosedSurface};
pub use vtu::{write_pvd, write_vtu, DataArray};
