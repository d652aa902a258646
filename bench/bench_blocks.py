"""Volumes larger than memory (issue 10): peak memory and time per voxel, block-wise.

Run ``python bench/bench_blocks.py --dir FOLDER`` (FOLDER needs about 14 GiB free;
``--quick`` uses volumes 8x smaller). It writes, once (kept for later runs):

- an 8 GiB uint16 raw volume, 2048 x 2048 x 1024 (``big_2048x2048x1024_uint16.raw``):
  a ball of radius 900 samples with a ripple on its surface, values 0..4000;
- the same field as a 4 GiB Zarr store, 2048 x 2048 x 512 (v3, chunks 64 x 512 x 512,
  zstd), the ball's upper half;
- a 1 GiB raw volume that fits in memory, 1024 x 1024 x 512 (the field at half size),

and then times whole commands (``python -m isoconvert convert ... -o out.ply``, one
process each, as a user runs them; peak resident memory is the child's own VmHWM):
the 8 GiB raw and the 4 GiB Zarr store with the default budget (1 GiB: they go
block-wise by themselves), and the 1 GiB volume in memory (``--max-memory 64G``)
against block-wise (``--max-memory 256M``), each run twice after a warm-up so that the
file is in the page cache in both. It prints seconds, nanoseconds per voxel, peak RSS
and the ratio of block-wise to in-memory time per voxel (target: at most 1.5), and
checks that the two 1 GiB meshes are byte-identical.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

LEVEL = 2000.5


def field_layer(n: int, k: int, nz_full: int) -> np.ndarray:
    """Layer k of the test field on an n x n grid whose full depth is nz_full:
    a ball of radius 0.44 n with a ripple, as uint16 values 0..4000."""
    r = np.arange(n, dtype=np.float32) - (n - 1) / 2
    y, x = np.meshgrid(r, r, indexing="ij")
    z = np.float32(k - (nz_full - 1) / 2)
    d = np.sqrt(x * x + y * y + z * z)
    ripple = 0.01 * n * np.sin(x * (24 / n)) * np.cos(y * (20 / n))
    value = 2000 + (0.44 * n - d + ripple) * (4000 / n)
    return np.clip(value, 0, 4000).astype(np.uint16)


def make_raw(path: Path, n: int, nz: int) -> None:
    if path.exists() and path.stat().st_size == n * n * nz * 2:
        return
    print(f"writing {path} ...", flush=True)
    tmp = path.with_suffix(".part")
    with open(tmp, "wb") as fh:
        for k in range(nz):
            fh.write(field_layer(n, k, nz).tobytes())
    tmp.replace(path)


def make_zarr(path: Path, n: int, nz: int) -> None:
    """The upper half of the 2 nz-deep field as a Zarr v3 store, nz layers."""
    import zarr

    if (path / "zarr.json").exists():
        return
    print(f"writing {path} ...", flush=True)
    store = zarr.create_array(
        str(path), shape=(nz, n, n), chunks=(64, 512, 512), dtype="uint16", zarr_format=3
    )
    for k0 in range(0, nz, 64):
        store[k0 : k0 + 64] = np.stack([field_layer(n, nz + k, 2 * nz) for k in range(k0, k0 + 64)])


# the child's own peak: VmHWM (ru_maxrss would count the parent's, from before exec)
CHILD = (
    "import sys, time\n"
    "from isoconvert.cli import main\n"
    "start = time.perf_counter()\n"
    "code = main()\n"
    "peak = [x for x in open('/proc/self/status') if x.startswith('VmHWM')][0].split()[1]\n"
    "print('BENCH', code, time.perf_counter() - start, peak, file=sys.stderr)\n"
)


def run(source: Path, out: Path, *extra: str) -> tuple[float, float]:
    """Seconds and peak RSS (MiB) of one conversion in its own process."""
    cmd = [sys.executable, "-c", CHILD, "convert", str(source), "-o", str(out)]
    cmd += ["--level", str(LEVEL), "--force", "--quiet", *extra]
    done = subprocess.run(cmd, capture_output=True, text=True)
    line = [x for x in done.stderr.splitlines() if x.startswith("BENCH")]
    if done.returncode or not line:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{done.stderr}")
    _, code, seconds, peak = line[-1].split()
    return float(seconds), int(peak) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, required=True, help="where the volumes are kept")
    parser.add_argument("--quick", action="store_true", help="volumes 8x smaller")
    args = parser.parse_args()
    folder = args.dir
    folder.mkdir(parents=True, exist_ok=True)
    big_n, big_z = (1024, 512) if args.quick else (2048, 1024)
    fit_n, fit_z = (512, 256) if args.quick else (1024, 512)
    big = folder / f"big_{big_n}x{big_n}x{big_z}_uint16.raw"
    fits = folder / f"fits_{fit_n}x{fit_n}x{fit_z}_uint16.raw"
    store = folder / f"big_{big_n}x{big_n}x{big_z // 2}.zarr"
    make_raw(big, big_n, big_z)
    make_raw(fits, fit_n, fit_z)
    make_zarr(store, big_n, big_z // 2)
    print(f"{os.cpu_count()} CPUs, {os.uname().machine}; level {LEVEL}")
    print(f"{'case':52s} {'seconds':>8s} {'ns/voxel':>9s} {'peak RSS':>10s}")

    def show(name: str, voxels: int, seconds: float, peak: float) -> None:
        print(f"{name:52s} {seconds:8.2f} {1e9 * seconds / voxels:9.2f} {peak:7.0f} MiB")

    out = folder / "out.ply"
    for name, source, voxels in (
        (f"raw {big.stat().st_size / 2**30:.0f} GiB, default budget", big, big_n**2 * big_z),
        (
            f"Zarr {big_n**2 * big_z // 2 * 2 / 2**30:.0f} GiB, default budget",
            store,
            big_n**2 * big_z // 2,
        ),
    ):
        seconds, peak = run(source, out)
        show(name, voxels, seconds, peak)
    voxels = fit_n**2 * fit_z
    a, b = folder / "in_memory.ply", folder / "blockwise.ply"
    run(fits, a, "--max-memory", "64G")  # warm-up: the file into the page cache
    memory, blocks = [], []
    for _ in range(2):
        memory.append(run(fits, a, "--max-memory", "64G"))
        blocks.append(run(fits, b, "--max-memory", "256M"))
    m, bl = min(memory), min(blocks)
    show(f"raw {fits.stat().st_size / 2**30:.0f} GiB in memory (--max-memory 64G)", voxels, *m)
    show(f"raw {fits.stat().st_size / 2**30:.0f} GiB block-wise (--max-memory 256M)", voxels, *bl)
    print(f"block-wise / in-memory time per voxel: {bl[0] / m[0]:.2f} (target <= 1.5)")
    same = filecmp.cmp(a, b, shallow=False)
    print(f"block-wise and in-memory files byte-identical: {'yes' if same else 'NO'}")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
