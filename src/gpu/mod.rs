//! Vulkan layer on ash. (Skeleton: being written.)
