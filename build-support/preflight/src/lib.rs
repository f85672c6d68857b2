//! Empty on purpose: this crate exists for its build script, which runs before lpmsplat's own
//! build script is linked against shaderc and stops the build with a message naming the missing
//! packages instead of a linker error.
