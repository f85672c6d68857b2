//! Undistortion of distorted camera models to pinhole. (Skeleton: being written.)
