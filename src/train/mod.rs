//! Training on the GPU: the loss, the optimizer, density control and the trainer loop.

pub mod loss;
