//! Localized Point Management. (Skeleton: being written.)
