//! CPU f64 reference implementation: the oracle for GPU kernels. (Skeleton: being written.)
