// 4-bit digits of 32-bit keys (the renderer sorts depths and tile ids, both 32 bits wide).
// Small digits keep the per-invocation counters of the stable scatter in registers for any
// subgroup size.
const uint RADIX_BITS = 4u;
const uint RADIX = 16u;

// `digit_mask` is RADIX - 1 except in a last pass that has fewer bits to sort: the bits above
// the sort's width are ignored, whatever the keys hold there.
uint radix_digit(uint key, uint shift, uint digit_mask) {
    return (key >> shift) & digit_mask;
}
