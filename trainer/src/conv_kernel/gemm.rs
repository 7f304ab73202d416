//! A safe, bounds-checked front to the `gemm` crate's single-threaded f32 matrix product.
//!
//! The one place of the trainer with `unsafe` code: `gemm::gemm` takes raw pointers and
//! strides. Every call goes through [`matmul`], which checks that each matrix's last element
//! lies inside its slice before handing the pointers over. The borrow checker already rules
//! out aliasing between the destination (`&mut`) and the operands (`&`).
//!
//! Why `gemm` (not `matrixmultiply`, not hand-written loops): both crates pick AVX2/FMA (or
//! AVX-512, NEON) kernels at run time. Measured on this machine for the conv shapes (chunk of
//! 32 samples): within 5% of each other in the first, channel-major layout; on the
//! channels-last shapes used now `gemm` was 1.2-1.5x faster on three of the four products
//! (matrixmultiply 8% faster on conv 2's weight gradient). burn's flex backend already links
//! `gemm`, so it adds no dependency. `Parallelism::None`: threads are split
//! over fixed sample chunks one level up (determinism, docs/decisions.md).

#![allow(unsafe_code)]

use crate::error::TrainError;

/// A read-only matrix view: element `(r, c)` is `data[r * row_stride + c * col_stride]`.
#[derive(Clone, Copy, Debug)]
pub struct MatRef<'a> {
    /// Backing storage.
    pub data: &'a [f32],
    /// Rows.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Distance between rows, in elements.
    pub row_stride: usize,
    /// Distance between columns, in elements.
    pub col_stride: usize,
}

impl<'a> MatRef<'a> {
    /// A row-major `rows x cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> MatRef<'a> {
        MatRef {
            data,
            rows,
            cols,
            row_stride: cols,
            col_stride: 1,
        }
    }

    /// The transpose of the row-major `cols x rows` matrix in `data` (no copy).
    pub fn transposed(data: &'a [f32], rows: usize, cols: usize) -> MatRef<'a> {
        MatRef {
            data,
            rows,
            cols,
            row_stride: 1,
            col_stride: rows,
        }
    }

    fn fits(&self) -> bool {
        if self.rows == 0 || self.cols == 0 {
            return true;
        }
        let last = (self.rows - 1).checked_mul(self.row_stride).and_then(|r| {
            (self.cols - 1)
                .checked_mul(self.col_stride)
                .and_then(|c| r.checked_add(c))
        });
        last.is_some_and(|last| last < self.data.len() && last <= isize::MAX as usize)
    }
}

/// `dst = lhs * rhs` (or `dst += lhs * rhs` with `accumulate`); `dst` is row-major
/// `lhs.rows x rhs.cols`. Errors on mismatched shapes or views that leave their slices.
pub fn matmul(
    dst: &mut [f32],
    lhs: MatRef<'_>,
    rhs: MatRef<'_>,
    accumulate: bool,
) -> Result<(), TrainError> {
    let (m, k, n) = (lhs.rows, lhs.cols, rhs.cols);
    if rhs.rows != k {
        return Err(TrainError::Shape(format!(
            "matmul: lhs is {m}x{k} but rhs has {} rows",
            rhs.rows
        )));
    }
    if dst.len() != m * n {
        return Err(TrainError::Shape(format!(
            "matmul: destination holds {} values, expected {m}x{n}",
            dst.len()
        )));
    }
    if !lhs.fits() || !rhs.fits() {
        return Err(TrainError::Shape(
            "matmul: a matrix view reaches past its slice".into(),
        ));
    }
    if m == 0 || n == 0 {
        return Ok(());
    }
    if k == 0 {
        if !accumulate {
            dst.fill(0.0);
        }
        return Ok(());
    }
    // SAFETY: `fits` checked that every element (r, c) of lhs and rhs lies inside its slice,
    // and dst is a contiguous row-major m x n slice of exactly m * n elements (checked above),
    // so every address gemm reads or writes is in bounds. dst is a unique borrow, so it cannot
    // alias lhs or rhs. Strides are at most isize::MAX (checked in `fits`, and dst's are n and
    // 1 with m * n elements allocated).
    unsafe {
        ::gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
            lhs.data.as_ptr(),
            lhs.col_stride as isize,
            lhs.row_stride as isize,
            rhs.data.as_ptr(),
            rhs.col_stride as isize,
            rhs.row_stride as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            ::gemm::Parallelism::None,
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matmul_matches_the_definition_with_transposed_views() {
        // lhs 2x3 row-major, rhs given as the transpose of a 2x3 (so 3x2).
        let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let b = [1.0, 0.0, -1.0, 2.0, 1.0, 0.5];
        let mut c = [10.0; 4];
        matmul(
            &mut c,
            MatRef::row_major(&a, 2, 3),
            MatRef::transposed(&b, 3, 2),
            false,
        )
        .unwrap();
        // row 0 of a . rows of b: (1 - 3, 2 + 2 + 1.5); row 1: (4 - 6, 8 + 5 + 3)
        assert_eq!(c, [-2.0, 5.5, -2.0, 16.0]);
        matmul(
            &mut c,
            MatRef::row_major(&a, 2, 3),
            MatRef::transposed(&b, 3, 2),
            true,
        )
        .unwrap();
        assert_eq!(c, [-4.0, 11.0, -4.0, 32.0]);
    }

    #[test]
    fn views_past_their_slice_are_refused() {
        let a = [1.0; 5];
        let mut c = [0.0; 4];
        let err = matmul(
            &mut c,
            MatRef::row_major(&a, 2, 3),
            MatRef::row_major(&a, 3, 2),
            false,
        );
        assert!(err.is_err());
    }
}
