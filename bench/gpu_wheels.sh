#!/usr/bin/env bash
# Download into .whl/ the wheels that `bench/gpu_check.py` needs on a GPU machine that has
# python 3.12 with torch, numpy, scipy, opencv-python-headless, matplotlib, click, rich, attrs
# and certifi but no network: the packages that `gcpcal simulate pushbroom` and the match
# (`gcpmatch.extract.extract_gcps`) import and such a machine lacks (read off sys.modules after
# both), at the versions of constraints.txt. `.whl/` is ignored by git (.gitignore); name it in the
# device call's `carry`. The check writes no GCP files, so pyogrio (33 MB, the GeoPackage layers
# that `gcpcal match` writes) stays behind: with it the wheels would not fit beside the working
# tree in a device call (64 MiB in all).
#
# Usage (from the repository root, where pip can reach the index):
#   bash bench/gpu_wheels.sh            # downloads, then prints each wheel's size and the total
# Then, on the device machine, before the check:
#   python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
#       --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD
# (docs/speed.md, "GPU check", gives the whole device command.)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
pin() { grep -i "^$1==" constraints.txt | head -n 1; }
# rasterio (with its GDAL), pyproj (with PROJ), pyerfa (erfa: time scales and frames), affine
# (grids), astropy-iers-data (Earth orientation tables). kornia (1.9 MB) and kornia_rs (5.3 MB)
# stay behind too: with them the wheels would not fit; the device matching then runs its
# torch-only path (gcpmatch/_features_torch.py), which gives the same matches.
wanted=(rasterio pyproj pyerfa affine astropy-iers-data)
specs=()
for name in "${wanted[@]}"; do
    spec=$(pin "$name")
    [ -n "$spec" ] || { echo "no pin for $name in constraints.txt" >&2; exit 1; }
    specs+=("$spec")
done
mkdir -p .whl
platforms=()
for tag in manylinux_2_28_x86_64 manylinux_2_27_x86_64 manylinux_2_24_x86_64 manylinux_2_17_x86_64 \
           manylinux2014_x86_64 manylinux1_x86_64; do
    platforms+=(--platform "$tag")
done
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${platforms[@]}" -d .whl "${specs[@]}"
ls -l .whl/*.whl | awk '{print $5, $NF; total += $5} END {printf "total %.1f MiB\n", total / 1048576}'
