//! Channels-last `f32` feature maps and the arithmetic both convolutions share: output
//! sizes and `sgemm`.

/// A channels-last feature map: `data[(y·width + x)·channels + c]`.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureMap {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// The `channels` values at pixel `p` (row-major pixel index).
    pub fn pixel(&self, p: usize) -> &[f32] {
        &self.data[p * self.channels..(p + 1) * self.channels]
    }

    /// Number of pixels.
    pub fn pixels(&self) -> usize {
        self.height * self.width
    }
}

/// Output side of a convolution or pooling window along one axis (`None`: no output).
pub fn output_side(input: usize, size: usize, stride: usize, padding: usize) -> Option<usize> {
    let padded = input + 2 * padding;
    (padded >= size).then(|| (padded - size) / stride + 1)
}

/// `c = a · b` for row-major `a` (`m×k`), `b` (`k×n`) and `c` (`m×n`).
pub fn matmul(a: &[f32], b: &[f32], c: &mut [f32], m: usize, k: usize, n: usize) {
    assert!(a.len() >= m * k && b.len() >= k * n && c.len() >= m * n);
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        c[..m * n].fill(0.0);
        return;
    }
    // SAFETY: the assert above keeps every index the row-major strides reach
    // (row < m, col < k or n) inside the three slices; `c` is borrowed mutably.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        );
    }
}
