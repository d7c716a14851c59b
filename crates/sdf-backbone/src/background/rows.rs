//! The background network's input rows: one per sample, `[PE_L(x/r, 1/r), the grid's features,
//! SH₄(d)]` — whole (training's), or with the columns of 1/r and its sines left out, the same on
//! every ray at one sample and folded into the first layer's bias per sample (a render's,
//! [`Layout::Folded`]).

use super::BackgroundModel;
use crate::module::Module;
use crate::real::Real;
use crate::scratch::Buf;

/// Where a sample's encoding lies in its row of the network's input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Layout {
    /// Every column (training's rows): `[x/r, 1/r]`, then per frequency l the sines of the four,
    /// then their cosines, then the grid's features and SH₄(d).
    Whole,
    /// [`Layout::Whole`] without the columns of 1/r and its sines (a render's rows): `[x/r]`,
    /// per frequency the sines of the three, then their cosines, then the grid's and SH₄(d).
    Folded,
}

impl Layout {
    /// The values per frequency and function (sin or cos): the point's three, and 1/r.
    fn per_function(self) -> usize {
        match self {
            Layout::Whole => 4,
            Layout::Folded => 3,
        }
    }

    /// The column of `sin(2^l v_j)` (`v` = x/r, then 1/r); its cosine's is [`Self::per_function`]
    /// further on.
    fn sine(self, l: usize, j: usize) -> usize {
        self.per_function() * (1 + 2 * l) + j
    }

    /// The columns of the positional encoding with `frequencies` frequencies.
    pub(super) fn encoding_width(self, frequencies: usize) -> usize {
        self.per_function() * (1 + 2 * frequencies)
    }
}

/// Rows of points whose sines are computed at once ([`BackgroundModel::write_point_sines`]): a
/// block's sines (2 × L × 3 values a row, f64) stay in the core's first-level cache for the
/// writes into their rows.
const SINE_ROWS: usize = 64;

/// Rays: their origins, unit directions and SH₄ of each direction.
pub(super) type Rays<'a, R> = (&'a [[R; 3]], &'a [[R; 3]], &'a [[R; 16]]);

/// The input rows of a set of samples ([`BackgroundModel::sample_rows`]).
pub(super) struct SampleRows<R: Real> {
    /// The network's inputs (rows × the layout's width).
    pub(super) input: Buf<R>,
    /// The grid's inputs (rows × 3; empty without a grid).
    pub(super) points: Buf<R>,
    /// Each sample's depth along its ray.
    pub(super) depths: Vec<R>,
}

impl BackgroundModel {
    /// The columns of a row in `layout`.
    pub(super) fn row_width(&self, layout: Layout) -> usize {
        let n_in = Module::<f32>::n_inputs(&self.net);
        n_in - Layout::Whole.encoding_width(self.frequencies) + layout.encoding_width(self.frequencies)
    }

    /// The network's input columns that hold the grid's features in `layout` (after the
    /// positional encoding, before SH₄(d); empty without a grid).
    pub(super) fn grid_columns(&self, layout: Layout) -> std::ops::Range<usize> {
        let start = layout.encoding_width(self.frequencies);
        start..start + self.grid.as_ref().map_or(0, Module::<f32>::n_outputs)
    }

    /// The whole row's columns that [`Layout::Folded`] leaves out (ascending): 1/r and its sines.
    pub(super) fn folded_columns(&self) -> Vec<usize> {
        let whole = Layout::Whole;
        let sines = (0..self.frequencies).flat_map(|l| [whole.sine(l, 3), whole.sine(l, 3) + whole.per_function()]);
        std::iter::once(3).chain(sines).collect()
    }

    /// The values of [`Self::folded_columns`] at sample k, in their order: its 1/r, then the sine
    /// and cosine of each frequency (`inv_r_sines`: [`Self::inverse_radius_sines`]).
    pub(super) fn folded_values<R: Real>(&self, k: usize, inv_r_sines: &[R]) -> Vec<R> {
        let per = 2 * self.frequencies;
        std::iter::once(self.inverse_radius(k)).chain(inv_r_sines[k * per..(k + 1) * per].iter().copied()).collect()
    }

    /// [`crate::sines::double_angles`] of every sample's 1/r (the same on every ray: sample k's
    /// is fixed), 2 × `frequencies` values per sample (sin, cos per frequency).
    pub(super) fn inverse_radius_sines<R: Real>(&self) -> Vec<R> {
        let per = 2 * self.frequencies;
        let mut out = vec![R::ZERO; self.samples * per];
        let mut sines = vec![0.0; per];
        for (k, out) in out.chunks_exact_mut(per.max(1)).enumerate() {
            crate::sines::double_angles(self.inverse_radius::<R>(k).to_f64(), self.frequencies, &mut sines);
            for (o, &v) in out.iter_mut().zip(&sines) {
                *o = R::of(v);
            }
        }
        out
    }

    /// Writes sample k of the ray (`o`, `d`, `sh` = SH₄(d)) as a row of the network's input in
    /// `layout`, but for the sines of its point x/r (the grid's columns left as they are;
    /// `inv_r_sines`: sample k's of [`Self::inverse_radius_sines`], for [`Layout::Whole`]) and,
    /// with a grid, its contracted point (`point`, 3 values; empty without a grid); returns the
    /// sample's depth and x/r, whose sines [`Self::write_point_sines`] writes for many rows at once.
    pub(super) fn sample_row<R: Real>(
        &self,
        layout: Layout,
        (o, d, sh): ([R; 3], [R; 3], &[R; 16]),
        k: usize,
        inv_r_sines: &[R],
        row: &mut [R],
        point: &mut [R],
    ) -> (R, [R; 3]) {
        let (inv_r, t) = self.sample_depth(o, d, k);
        let p = [0, 1, 2].map(|j| (o[j] + t * d[j]) * inv_r);
        row[..3].copy_from_slice(&p);
        if layout == Layout::Whole {
            row[3] = inv_r;
            for l in 0..self.frequencies {
                row[layout.sine(l, 3)] = inv_r_sines[2 * l];
                row[layout.sine(l, 3) + layout.per_function()] = inv_r_sines[2 * l + 1];
            }
        }
        if self.view_dependent {
            let n = row.len();
            row[n - 16..].copy_from_slice(sh);
        }
        if !point.is_empty() {
            // Contracted: radius (2 − 1/r)/2 ∈ [½, 1) of the grid's cube.
            let c = (R::of(2.0) - inv_r) * R::of(0.5);
            point.copy_from_slice(&p.map(|v| v * c));
        }
        (t, p)
    }

    /// The sines of every row's point x/r (`points`: 3 values a row) written into their columns
    /// of `input` (rows in `layout`), [`SINE_ROWS`] rows at a time: with `series`, by
    /// [`crate::sines::double_angles_of_all`] (a render's), else by libm's `sin_cos` of each
    /// ([`crate::sines::double_angles_of_each`], training's bits).
    pub(super) fn write_point_sines<R: Real>(&self, layout: Layout, points: &[f64], input: &mut [R], series: bool) {
        let (f, n_in, half) = (self.frequencies, self.row_width(layout), layout.per_function());
        let mut sines = vec![0.0f64; 2 * f * 3 * SINE_ROWS];
        for (points, input) in points.chunks(3 * SINE_ROWS).zip(input.chunks_mut(n_in * SINE_ROWS)) {
            let n = points.len();
            let sines = &mut sines[..2 * f * n];
            if series {
                crate::sines::double_angles_of_all(points, f, sines);
            } else {
                crate::sines::double_angles_of_each(points, f, sines);
            }
            for (i, row) in input.chunks_exact_mut(n_in).enumerate() {
                for l in 0..f {
                    let (sin, cos) = (&sines[2 * l * n + 3 * i..][..3], &sines[(2 * l + 1) * n + 3 * i..][..3]);
                    let at = layout.sine(l, 0);
                    for j in 0..3 {
                        row[at + j] = R::of(sin[j]);
                        row[at + half + j] = R::of(cos[j]);
                    }
                }
            }
        }
    }

    /// With a grid, its features at `points` (rows × 3) written into their columns of `input`
    /// (rows in `layout`).
    fn add_grid_features<R: Real>(&self, layout: Layout, p_grid: &[R], points: &[R], input: &mut [R]) {
        let Some(grid) = &self.grid else { return };
        let (columns, n_in) = (self.grid_columns(layout), self.row_width(layout));
        let mut features = Buf::<R>::zeroed(points.len() / 3 * columns.len());
        grid.forward(p_grid, points, &mut features, &mut []);
        for (row, f) in input.chunks_exact_mut(n_in).zip(features.chunks_exact(columns.len())) {
            row[columns.clone()].copy_from_slice(f);
        }
    }

    /// The input rows in `layout` of `rows` samples, row i being sample `which(i) = (ray, k)` of
    /// the rays (`origins`, `directions`, `sh`), with the grid's features (`p_grid`: its tables):
    /// [`Layout::Whole`]'s sines by libm's (training's bits), [`Layout::Folded`]'s by their
    /// series (a render's).
    pub(super) fn sample_rows<R: Real>(
        &self,
        layout: Layout,
        p_grid: &[R],
        (origins, directions, sh): Rays<'_, R>,
        inv_r_sines: &[R],
        rows: usize,
        which: impl Fn(usize) -> (usize, usize),
    ) -> SampleRows<R> {
        let n_in = self.row_width(layout);
        // Every column of every row is written below (the encoding's, the grid's, SH₄(d)'s).
        let mut input = Buf::<R>::to_overwrite(rows * n_in);
        let mut points = Buf::<R>::to_overwrite(if self.grid.is_some() { rows * 3 } else { 0 });
        let mut depths = vec![R::ZERO; rows];
        let mut on_sphere = vec![0.0f64; 3 * rows];
        let per = 2 * self.frequencies;
        for i in 0..rows {
            let (r, k) = which(i);
            let point = points.get_mut(3 * i..3 * i + 3).unwrap_or_default();
            let row = &mut input[i * n_in..(i + 1) * n_in];
            let ray = (origins[r], directions[r], &sh[r]);
            let (t, p) = self.sample_row(layout, ray, k, &inv_r_sines[k * per..(k + 1) * per], row, point);
            depths[i] = t;
            on_sphere[3 * i..3 * i + 3].copy_from_slice(&p.map(R::to_f64));
        }
        self.write_point_sines(layout, &on_sphere, &mut input, layout == Layout::Folded);
        self.add_grid_features(layout, p_grid, &points, &mut input);
        SampleRows { input, points, depths }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The encoding's sines by double angles against each evaluated directly in f64, over the
    /// range of (x/r, 1/r) and ten frequencies (2⁹ = 512 the highest), in both layouts.
    #[test]
    fn the_encodings_sines_by_double_angles_are_those_of_each_frequency() {
        let model = BackgroundModel::with_view(16, 10, 8, 1, false);
        let inv_r_sines = model.inverse_radius_sines::<f64>();
        for layout in [Layout::Whole, Layout::Folded] {
            let mut row = vec![0.0f64; model.row_width(layout)];
            let mut worst = 0.0f64;
            for i in 0..200 {
                let a = i as f64 * 0.731;
                let (o, d) = ([0.3 * a.sin(), -0.2, 0.1 * a.cos()], [a.cos() * 0.6, a.sin() * 0.6, 0.8]);
                for k in 0..16 {
                    let (_, p) = model.sample_row(layout, (o, d, &[0.0; 16]), k, &inv_r_sines[20 * k..20 * k + 20], &mut row, &mut []);
                    model.write_point_sines(layout, &p, &mut row, k % 2 == 0);
                    let inv_r: f64 = model.inverse_radius(k);
                    let values = [row[0], row[1], row[2], inv_r];
                    let encoded = if layout == Layout::Whole { 4 } else { 3 };
                    assert_eq!(layout == Layout::Whole, row[3] == inv_r, "{layout:?}: 1/r's column");
                    for l in 0..10 {
                        for (j, v) in values.iter().enumerate().take(encoded) {
                            let x = f64::from(1u32 << l) * v;
                            let (sin, cos) = (row[layout.sine(l, j)], row[layout.sine(l, j) + encoded]);
                            worst = worst.max((sin - x.sin()).abs()).max((cos - x.cos()).abs());
                        }
                    }
                }
            }
            assert!(worst <= 1e-12, "{layout:?}: off by {worst:e}");
        }
    }

    /// The columns a folded row leaves out are those of 1/r and its sines (whose values
    /// `folded_values` gives, in their order), and the rest of the whole row is the folded row,
    /// column for column.
    #[test]
    fn a_folded_row_is_the_whole_row_without_the_inverse_radius_columns() {
        let model = BackgroundModel::with_view(16, 3, 8, 1, true);
        let (ray, inv_r_sines) = (([0.1, -0.2, 0.3], [0.6, 0.0, 0.8], &[0.5f64; 16]), model.inverse_radius_sines::<f64>());
        let (mut whole, mut folded) = (vec![0.0; model.row_width(Layout::Whole)], vec![0.0; model.row_width(Layout::Folded)]);
        let (_, p) = model.sample_row(Layout::Whole, ray, 5, &inv_r_sines[30..36], &mut whole, &mut []);
        model.write_point_sines(Layout::Whole, &p, &mut whole, true);
        model.sample_row(Layout::Folded, ray, 5, &[], &mut folded, &mut []);
        model.write_point_sines(Layout::Folded, &p, &mut folded, true);
        let left_out = model.folded_columns();
        assert_eq!(left_out, [3, 7, 11, 15, 19, 23, 27]);
        let inv_r: f64 = model.inverse_radius(5);
        let expected: Vec<f64> = std::iter::once(inv_r).chain(inv_r_sines[30..36].iter().copied()).collect();
        assert_eq!(left_out.iter().map(|&c| whole[c]).collect::<Vec<_>>(), expected);
        assert_eq!(model.folded_values(5, &inv_r_sines), expected, "the values folded for sample 5");
        let kept: Vec<f64> = whole.iter().enumerate().filter(|(c, _)| !left_out.contains(c)).map(|(_, &v)| v).collect();
        assert_eq!(kept, folded);
    }
}
