#!/usr/bin/env bash
# Regenerates the COLMAP sparse-model fixtures in crates/datasets/tests/fixtures/colmap/ with the
# real client (Debian's colmap 3.8, CPU only). Not run by CI: the committed models are the
# fixtures, and a rerun gives other (equally valid) models, since COLMAP's RANSAC is random.
#
#   golden/      a golden scene rendered by this crate: the textured mesh bob (CC0, shared data)
#                on the DTU rig, 49 views of 800×600, textured backdrop; one shared PINHOLE camera
#                with the renderer's intrinsics (f = 1.8·600 = 1080, principal point 400, 300 in
#                COLMAP's half-integer pixel centres) held fixed, as for a calibrated camera;
#                features only inside the object's masks (--ImageReader.mask_path, as users of
#                object captures with masks do): the backdrop is a pattern at infinity, whose
#                features fix rotations only and match ambiguously (without the masks COLMAP's
#                cameras were off by 0.87° mean and a golden run through them trained to 2.9×
#                the true cameras' Chamfer, 1.2× after ICP; with them, see BENCHMARKS.md).
#                (The built-in analytic scene is too poorly textured for SIFT: COLMAP registered
#                at most 33 of its 49 views with known intrinsics, and with free intrinsics it
#                converged to focal lengths off by 15–50 %.)
#   dtu_scan24/  DTU scan 24 (IDR/NeuS preprocessing) downscaled 1600×1200 → 800×600 (area
#                average); one shared OPENCV camera, principal point refined; at most 1024 SIFT
#                features per image to keep images.bin/txt small.
# Each gets sparse/0/{cameras,images,points3D}.bin and text/{cameras,images,points3D}.txt.
#
# Needs: apt-get install -y colmap; the shared data folder (../shared/data: meshes/bob, dtu_scan24).
set -euo pipefail
cd "$(dirname "$0")/.."
WORK=${WORK:-$(mktemp -d)}
THREADS=${THREADS:-2}
OUT=crates/datasets/tests/fixtures/colmap
export QT_QPA_PLATFORM=offscreen

# Inputs: the golden scene in the IDR layout (rendered by this crate) and DTU's images
# downscaled by 2 with this crate's image code (the ignored helper test writes both).
PSNEUS_COLMAP_INPUTS="$WORK" CARGO_BUILD_JOBS=1 \
    cargo test -p datasets --test colmap -- --ignored --exact write_colmap_fixture_inputs

run_colmap() { # name image_dir camera_model "extractor options" "mapper options"
    local name=$1 images=$2 model=$3 extract=$4 map=$5 ws="$WORK/$1"
    rm -rf "$ws" "$OUT/$name"
    mkdir -p "$ws/sparse" "$OUT/$name/sparse/0" "$OUT/$name/text"
    # shellcheck disable=SC2086
    colmap feature_extractor --database_path "$ws/database.db" --image_path "$images" \
        --ImageReader.single_camera 1 --ImageReader.camera_model "$model" \
        --SiftExtraction.use_gpu 0 --SiftExtraction.num_threads "$THREADS" $extract
    colmap exhaustive_matcher --database_path "$ws/database.db" \
        --SiftMatching.use_gpu 0 --SiftMatching.num_threads "$THREADS"
    # shellcheck disable=SC2086
    colmap mapper --database_path "$ws/database.db" --image_path "$images" \
        --output_path "$ws/sparse" --Mapper.num_threads "$THREADS" $map
    ls "$ws/sparse" # one model, 0, when every image registered in one piece
    cp "$ws/sparse/0/cameras.bin" "$ws/sparse/0/images.bin" "$ws/sparse/0/points3D.bin" "$OUT/$name/sparse/0/"
    colmap model_converter --input_path "$ws/sparse/0" --output_path "$OUT/$name/text" --output_type TXT
    colmap model_analyzer --path "$ws/sparse/0"
}

# COLMAP reads the mask of image NAME as NAME.png (zero: no features).
mkdir -p "$WORK/golden/colmap_mask"
for f in "$WORK/golden/mask/"*.png; do cp "$f" "$WORK/golden/colmap_mask/$(basename "$f").png"; done
run_colmap golden "$WORK/golden/image" PINHOLE \
    "--ImageReader.camera_params 1080,1080,400,300 --ImageReader.mask_path $WORK/golden/colmap_mask" \
    "--Mapper.ba_refine_focal_length 0 --Mapper.ba_refine_extra_params 0"
run_colmap dtu_scan24 "$WORK/dtu_scan24_800/images" OPENCV \
    "--SiftExtraction.max_num_features 1024" \
    "--Mapper.ba_refine_principal_point 1"
du -sh "$OUT"/*/sparse/0 "$OUT"/*/text
