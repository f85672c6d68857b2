//! The forward pipeline's GPU building blocks: prefix sums and the key–value radix sort.

pub mod backward;
pub mod layout;
pub mod scan;
pub mod sort;
