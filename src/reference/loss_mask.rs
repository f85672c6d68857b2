//! Oracle of `glsl/train/mask_grads.comp`: a view's loss gradient with the pixels of its
//! unlearned cells zeroed ([`crate::scene::loss_masks`]).

/// The cell of pixel `(x, y)` in a `cols × rows` grid over a `width × height` image, row-major.
pub fn cell_of(x: u32, y: u32, width: u32, height: u32, cols: u32, rows: u32) -> usize {
    let cx = (x as u64 * cols as u64 / width as u64) as usize;
    let cy = (y as u64 * rows as u64 / height as u64) as usize;
    cy * cols as usize + cx
}

/// `grad` (interleaved RGB, `width × height` pixels) with every pixel of a `false` cell set to 0.
pub fn mask_gradient(
    grad: &[f64],
    width: u32,
    height: u32,
    cells: &[bool],
    cols: u32,
    rows: u32,
) -> Vec<f64> {
    let mut out = grad.to_vec();
    for y in 0..height {
        for x in 0..width {
            if !cells[cell_of(x, y, width, height, cols, rows)] {
                let p = (y * width + x) as usize;
                out[3 * p..3 * p + 3].fill(0.0);
            }
        }
    }
    out
}
