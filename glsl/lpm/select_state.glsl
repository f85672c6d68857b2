// Radix selection of order statistics (see select_histogram.comp and select_pick.comp). The state
// buffer layout, in u32 (src/lpm/gpu.rs mirrors the indices):
const uint SEL_N = 0u;          // elements taking part
const uint SEL_VALID = 1u;      // 1 when the selection is defined (set by pass 0 of the pick)
const uint SEL_RANK = 2u;       // two ranks still to find inside the current prefix (2, 3)
const uint SEL_PREFIX = 4u;     // two keys being built, one byte per pass from the top (4, 5)
const uint SEL_THRESHOLD = 6u;  // the result as f32 bits
const uint SEL_RESET = 7u;      // opacity reset: how many Gaussians were reset
const uint SEL_STATE_LEN = 8u;
const uint RADIX = 256u;
// The histogram of pass p, rank slot w, bin b lives at hist[(p * 2 + w) * RADIX + b].
