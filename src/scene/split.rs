//! Train/test split and scene extent. (Skeleton: being written.)
