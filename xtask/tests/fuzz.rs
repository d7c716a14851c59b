//! The parsers under mutated bytes (a short run of `cargo xtask fuzz`, in process) and the
//! inputs fuzzing found, kept as regression tests.

use std::path::Path;
use xtask::fuzz::{CaseRange, Target, run_cases, seeds_of, select};

fn target(name: &str) -> Target {
    select(&[name.to_string()]).unwrap().remove(0)
}

#[test]
fn every_parser_answers_mutated_bytes_with_a_value_or_an_error() {
    let targets = select(&[]).unwrap();
    let range = CaseRange { seed: 7, first: 0, cases: 28_000, threads: 2 };
    let report = run_cases(&targets, &seeds_of(&targets), &range, None, None, &|_| {});
    for (name, tally) in &report.tallies {
        assert!(tally.cases >= 2_000, "{name}: {} cases", tally.cases);
        // The mutants are not all rejected at the first byte: some get through whole parsers.
        assert!(tally.accepted > 0, "{name}: no mutant accepted");
        assert!(tally.accepted < tally.cases, "{name}: every mutant accepted");
    }
    let found: Vec<String> = report.findings.iter().map(|f| format!("{} case {}: {}", f.target, f.case, f.message)).collect();
    assert!(found.is_empty(), "{found:#?}");
}

#[test]
fn cases_are_reproducible_from_seed_and_index_whatever_the_thread_count() {
    let t = [target("npy"), target("ply")];
    let seeds = seeds_of(&t);
    let run = |seed: u64, first: u64, threads: usize| run_cases(&t, &seeds, &CaseRange { seed, first, cases: 3_000, threads }, None, None, &|_| {});
    let (one, three) = (run(3, 100, 1), run(3, 100, 3));
    assert_eq!(one.digest, three.digest, "the cases or their verdicts depend on the thread count");
    assert_eq!(one.tallies[0].1.accepted, three.tallies[0].1.accepted);
    // The digest sees the inputs: another seed or another range gives other cases.
    assert_ne!(one.digest, run(4, 100, 2).digest);
    assert_ne!(one.digest, run(3, 101, 2).digest);
}

#[test]
fn colmap_camera_of_absurd_width_is_rejected_not_scanned_for_minutes() {
    // Found by `cargo xtask fuzz`: a binary camera 268 435 520 pixels wide made the undistortion
    // plan walk its border ~100 times (110 s for one file).
    let t = target("colmap-bin");
    let mut input = (t.seeds)().remove(0);
    // cameras.bin: count (8), camera 1 (4 + 4 + 8 + 8 + 4 · 8), camera 2: id, model, width.
    input[72..80].copy_from_slice(&268_435_520u64.to_le_bytes());
    let started = std::time::Instant::now();
    let err = (t.run)(&input).unwrap_err();
    assert!(err.contains("cameras.bin") && err.contains("exceeds"), "{err}");
    // 110 s before the fix; a bounded scan is milliseconds (generous for a loaded machine).
    assert!(started.elapsed().as_secs_f64() < 30.0);
}

#[test]
fn npy_shape_without_parenthesis_or_overflowing_is_an_error() {
    for header in ["'shape': é)", "'shape': )", "'shape': (4294967296, 4294967296, 4294967296)"] {
        let dict = format!("{{'descr': '<f8', 'fortran_order': False, {header}, }}");
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend((dict.len() as u16).to_le_bytes());
        bytes.extend(dict.as_bytes());
        let err = datasets::parse::npy(&bytes, Path::new("a.npy")).unwrap_err().to_string();
        assert!(err.contains("a.npy") && err.contains("shape"), "{header}: {err}");
    }
}

#[test]
fn ply_counts_beyond_the_file_and_bad_indices_are_errors() {
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    for (body, needle) in [
        ("element face 99999999999\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "room"),
        ("element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n", "index"),
        ("element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", "non-finite"),
    ] {
        let err = datasets::parse::ply(format!("{head}{body}").as_bytes(), Path::new("m.ply")).unwrap_err().to_string();
        assert!(err.contains("m.ply") && err.contains(needle), "{needle}: {err}");
    }
    let text = "ply\nformat ascii 1.0\nelement nothing 5\nend_header\n0 0 0 1 0 0 0 1 0\n";
    let err = datasets::parse::ply(text.as_bytes(), Path::new("m.ply")).unwrap_err().to_string();
    assert!(err.contains("m.ply") && err.contains("without properties"), "{err}");
}
