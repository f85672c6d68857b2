// 4-bit digits of 64-bit keys stored as uvec2(low word, high word). Small digits keep the
// per-invocation counters of the stable scatter in registers for any subgroup size.
const uint RADIX_BITS = 4u;
const uint RADIX = 16u;

uint radix_digit(uvec2 key, uint shift) {
    uint word = shift < 32u ? key.x : key.y;
    return (word >> (shift & 31u)) & (RADIX - 1u);
}
