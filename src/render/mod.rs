//! The renderer on the GPU: the data contract (`layout`), the forward pass (`forward`) and its
//! building blocks (prefix sums, radix sort, bands of tile rows for frames past one binding of
//! pairs), the backward pass (`backward`), 2DGS's surfels
//! (`surfel`, on the same binning), and generated scenes for benchmarks.

pub mod backward;
pub mod bands;
pub mod blocking;
pub mod decoder;
pub mod dispatch_size;
pub mod filter3d;
pub mod forward;
pub mod layout;
pub mod projected;
pub mod scan;
pub mod sort;
pub mod spacetime;
pub mod surfel;
pub mod synthetic;
pub mod view;
