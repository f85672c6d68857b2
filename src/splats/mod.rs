//! The Gaussian model: parameters, PLY in/out (Inria layout), initialisation. (Skeleton.)
