//! The output folder every command that writes one (`train`, `bench trade`, `bench merge`)
//! prepares before any work is done. The library's `bench trade` harness prepares its own, so
//! the function lives in [`lpmsplat::error`]; the commands reach it by this name.

pub use lpmsplat::error::prepare_output;
