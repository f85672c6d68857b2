// A u32 whose unsigned order is the total order of f32 (as Rust's `f32::total_cmp`): negative
// values have all bits flipped, the others only the sign bit. −0 sorts just below +0; NaNs with
// the sign bit clear sort above +inf. src/reference/lpm_membership.rs `float_key` is the CPU twin.
uint float_key(uint bits) {
    return (bits & 0x80000000u) != 0u ? ~bits : (bits | 0x80000000u);
}
uint key_bits(uint key) {
    return (key & 0x80000000u) != 0u ? (key & 0x7FFFFFFFu) : ~key;
}
