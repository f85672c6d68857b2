//! 2D Gaussian Splatting (surfels) on the GPU: the data contract beside 3DGS's ([`layout`]) and
//! the forward pass ([`forward`]), which shares 3DGS's depth sort, binning, tile sort and tile
//! ranges and replaces the preprocess and the rasterizer, and the backward pass ([`backward`]).
//! Every kernel mirrors [`crate::reference::surfel`].

pub mod backward;
pub mod forward;
pub mod layout;
pub mod regularise;
