//! A hash grid's features against an oracle written out here, row by row: the trilinear sum of
//! each level's eight corners (instant-ngp's spatial hash on the levels too fine for a dense
//! table), to the bit — for the blocked level kernels and their row-by-row fallback.

mod common;

use common::*;
use sdf_backbone::*;

/// The features of one point, row by row and corner by corner: what every pass of the grid must
/// compute, the same multiply-adds in the same order (corner c's weight `wx · wy · wz`, its bits
/// x = 1, y = 2, z = 4; each feature `w · t + acc` fused, corners in order).
fn oracle<R: Real>(grid: &HashGrid, params: &[R], x: &[R]) -> Vec<R> {
    let f = grid.config().features;
    let table = 1usize << grid.config().log2_table;
    let mut out = vec![R::ZERO; grid.config().levels * f];
    for level in 0..grid.active_levels {
        let n = grid.resolutions()[level];
        let entries = &params[grid.level_params(level)];
        let dense = entries.len() / f < table;
        let scale = R::of(f64::from(n) * 0.5);
        let mut cell = [0u32; 3];
        let mut frac = [R::ZERO; 3];
        for d in 0..3 {
            let p = ((x[d] + R::ONE) * scale).max(R::ZERO).min(R::of(f64::from(n)));
            let c = p.floor().min(R::of(f64::from(n) - 1.0));
            cell[d] = c.to_f64() as u32;
            frac[d] = p - c;
        }
        for c in 0..8u32 {
            let bit = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let v = [0, 1, 2].map(|d| cell[d] + bit[d]);
            let index = if dense {
                (v[0] + (n + 1) * (v[1] + (n + 1) * v[2])) as usize
            } else {
                ((v[0] ^ v[1].wrapping_mul(2_654_435_761) ^ v[2].wrapping_mul(805_459_861)) as usize) & (table - 1)
            };
            let w = [0, 1, 2].map(|d| if bit[d] == 1 { frac[d] } else { R::ONE - frac[d] });
            let weight = w[0] * w[1] * w[2];
            for k in 0..f {
                out[level * f + k] = weight.mul_add(entries[index * f + k], out[level * f + k]);
            }
        }
    }
    out
}

/// Guards the level kernels (blocks of rows, features written straight into their columns of
/// the rows, DECISIONS §57): `forward` and `forward_keeping_tangents` equal the oracle to the
/// bit, in f64 and f32, for feature counts with a kernel (1, 2, 4) and without (3, the
/// row-by-row fallback), dense and hashed levels, points outside the grid, a level switched
/// off, and row counts around the block of 16 (1, 15, 16, 17, 37).
#[test]
fn a_hash_grids_features_are_the_corners_trilinear_sums_to_the_bit() {
    for features in [1, 2, 3, 4] {
        let mut grid = HashGrid::new(HashGridConfig { levels: 4, features, log2_table: 7, base_resolution: 3, finest_resolution: 19 });
        let params = random_params(Module::<f64>::n_params(&grid), 0.5, 11);
        let params32: Vec<f32> = params.iter().map(|&p| p as f32).collect();
        for active in [4, 3] {
            grid.active_levels = active;
            for rows in [1, 15, 16, 17, 37] {
                // Points in [−1.1, 1.1]³: a few outside the grid, clamped to it.
                let input = random_params(3 * rows, 1.1, rows as u64);
                let input32: Vec<f32> = input.iter().map(|&x| x as f32).collect();
                check(&grid, &params, &input, &format!("f64, {features} features, {active} levels on, {rows} rows"));
                check(&grid, &params32, &input32, &format!("f32, {features} features, {active} levels on, {rows} rows"));
            }
        }
    }
}

fn check<R: Real>(grid: &HashGrid, params: &[R], input: &[R], name: &str) {
    let rows = input.len() / 3;
    let n_out = Module::<R>::n_outputs(grid);
    let bits = |v: &[R]| v.iter().map(|x| x.to_f64().to_bits()).collect::<Vec<_>>();
    let expected: Vec<R> = input.chunks_exact(3).flat_map(|x| oracle(grid, params, x)).collect();
    let mut output = vec![R::of(f64::NAN); rows * n_out];
    grid.forward(params, input, &mut output, &mut []);
    assert_eq!(bits(&output), bits(&expected), "{name}: forward");
    let mut kept = vec![R::of(f64::NAN); rows * n_out];
    let mut ctx = vec![R::ZERO; rows * TangentModule::<R>::tangent_ctx_per_row(grid)];
    grid.forward_keeping_tangents(params, input, &mut kept, &mut ctx);
    assert_eq!(bits(&kept), bits(&expected), "{name}: forward keeping tangents");
}
