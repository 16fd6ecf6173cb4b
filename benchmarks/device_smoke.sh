#!/usr/bin/env bash
# Every command that takes --device, end to end on one device: exit code and seconds per command.
# Usage: DEV=cuda bash benchmarks/device_smoke.sh   (DEV=cpu to try it; STEPS: optimize steps, default 30;
# OUT: where each command's JSON and stderr go, default a temporary folder). Needs the package importable
# (pip install -e . or PYTHONPATH=.). Last run with DEV=cuda: NVIDIA H200, torch 2.11, 2026-11-26, every
# command exit 0, optimize_joint included (docs/benchmarks.md, summary); simulate_field (a field PSF set,
# ~10 min on 2 CPU cores, 20 s on the H200) ran on its own there on 2026-11-27 after two fixes.
DEV=${DEV:-cuda}; T=$(mktemp -d); O=${OUT:-$T}; mkdir -p "$O"
M="python3 -m metalens_cli"
run() {
  local name=$1; shift; local t0; t0=$(date +%s%N)
  "$@" > "$O/$name.json" 2> "$O/$name.err"; local rc=$?
  echo "$name rc=$rc $(( ($(date +%s%N) - t0) / 1000000 )) ms"; [ $rc = 0 ] || tail -5 "$O/$name.err"
}
run optimize $M optimize presets/quick-split-spectrum.toml -o "$T/opt" --steps "${STEPS:-30}" --device "$DEV" --json --quiet
run optimize_joint $M optimize presets/quick-joint-filter.toml -o "$T/joint" --steps "${STEPS:-30}" --device "$DEV" --json --quiet
run psf_scan $M psf-scan --design "$T/opt" --device "$DEV" -o "$T/scan.exr" --json --quiet
run psf_scan_2d $M psf-scan --design hyperbolic:532nm --preset presets/hyperbolic-532.toml --propagator asm \
  --wavelengths 457nm,530nm,628nm --depths inf --device "$DEV" -o "$T/scan2d.exr" --json --quiet
run simulate $M simulate "$T/opt" --device "$DEV" --pixels 128 -o "$T/sim" --json
run simulate_field $M simulate hyperbolic:532nm --preset presets/hyperbolic-532.toml --field auto --pixels 512 \
  --limit 1 --device "$DEV" -o "$T/simfield" --json
run reconstruct_train $M reconstruct train hyperbolic:532nm --preset tests/design/tiny_reconstruct.toml \
  --camera presets/hyperbolic-532.toml -o "$T/rec" --steps 20 --device "$DEV" --json --quiet
run reconstruct_apply $M reconstruct apply "$T/rec" "$T"/sim/*_obstructed.exr -o "$T/applied" --device "$DEV" --json --quiet
run evaluate $M evaluate hyperbolic:532nm --preset presets/hyperbolic-532.toml --recon "$T/rec" --pixels 128 --seed 0 \
  --obstruction dirt --device "$DEV" --json --quiet
