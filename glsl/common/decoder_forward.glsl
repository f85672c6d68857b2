// The decoder's forward for PIXELS pixels at once (decoder.glsl has the network): every weight
// is read once for all of them, which on CPU drivers, where a load of a value that is the same
// for every lane still loops over the subgroup's lanes, divides the weight loads by PIXELS.
// Include after declaring the specialisation constant PIXELS and the weights `dec_w[]`.

// rgb[p] = sigmoid(base[p] + W2 ReLU(W1 x[p])).
void decode_pixels(float x[PIXELS][DEC_INPUTS], vec3 base[PIXELS], out vec3 rgb[PIXELS]) {
    float h[PIXELS][DEC_HIDDEN];
    for (uint r = 0u; r < DEC_HIDDEN; r++) {
        float s[PIXELS];
        for (uint p = 0u; p < PIXELS; p++) s[p] = 0.0;
        for (uint c = 0u; c < DEC_INPUTS; c++) {
            float wv = dec_w[r * DEC_INPUTS + c];
            for (uint p = 0u; p < PIXELS; p++) s[p] += wv * x[p][c];
        }
        for (uint p = 0u; p < PIXELS; p++) h[p][r] = max(s[p], 0.0);
    }
    for (uint o = 0u; o < DEC_OUTPUTS; o++) {
        float y[PIXELS];
        for (uint p = 0u; p < PIXELS; p++) y[p] = base[p][o];
        for (uint c = 0u; c < DEC_HIDDEN; c++) {
            float wv = dec_w[DEC_W2 + o * DEC_HIDDEN + c];
            for (uint p = 0u; p < PIXELS; p++) y[p] += wv * h[p][c];
        }
        for (uint p = 0u; p < PIXELS; p++) rgb[p][o] = 1.0 / (1.0 + exp(-y[p]));
    }
}
