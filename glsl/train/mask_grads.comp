#version 460
// A view's loss mask (src/scene/loss_masks.rs): dL/d(image) is zeroed at the pixels of the cells
// the run does not learn, so those pixels pull on no Gaussian (in a partition block's view, the
// content another block owns). The loss value is left as it was: it counts every pixel, and an
// SSIM window at a mask edge still reads its masked neighbours; only the pull is cut.
// Cell (cx, cy) of a cols × rows grid holds pixel (x, y) with cx = x·cols / W and
// cy = y·rows / H in integers; the cells are bits, row-major from bit 0 of word mask_offset.
// One invocation a pixel (the gradient is interleaved RGB, as the image).
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Mask { uint mask[]; };
layout(std430, set = 0, binding = 1) buffer Grad { float grad[]; };
layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint mask_offset;
    uint cols;
    uint rows;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= width * height) return;
    uint x = i % width, y = i / width;
    uint cell = (y * rows / height) * cols + x * cols / width;
    if (((mask[mask_offset + cell / 32u] >> (cell % 32u)) & 1u) == 0u) {
        grad[3u * i] = 0.0;
        grad[3u * i + 1u] = 0.0;
        grad[3u * i + 2u] = 0.0;
    }
}
