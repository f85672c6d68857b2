// Digits of 32-bit keys (the renderer sorts depths and tile ids, both 32 bits wide): 4 bits, or
// 5 where a 5-bit pass saves a whole pass (13-bit tile keys: 5 + 4 + 4 instead of 4 · 4). Small
// digits keep the per-invocation counters of the stable scatter in registers for any subgroup
// size. A specialisation constant, so each width is its own pipeline with fixed loop bounds.
layout(constant_id = 3) const uint RADIX_BITS = 4u;
const uint RADIX = 1u << RADIX_BITS;
// Whether the pass may drop keys (push constant drop_keys, a sorter made to drop): a sorter
// that never drops compiles the test out.
layout(constant_id = 4) const bool DROPS = false;

// `digit_mask` is RADIX - 1 except in a last pass that has fewer bits to sort: the bits above
// the sort's width are ignored, whatever the keys hold there.
uint radix_digit(uint key, uint shift, uint digit_mask) {
    return (key >> shift) & digit_mask;
}
