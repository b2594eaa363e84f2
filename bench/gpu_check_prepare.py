"""Prepare the GPU check (``bench/gpu_check.sh``): the wheels the device machine lacks, and one scene.

    python bench/gpu_check_prepare.py [--scene-dir DIR]

Run here, in the repository root, on a machine with the registry (never on the device machine,
which reaches nothing). The device image has Python 3.12 with torch, numpy, scipy, OpenCV,
numba, pytest, rich and psutil but none of gsplat, pydantic, zarr, open3d, pycolmap, lzfse or
OpenEXR. Their cp312 manylinux wheels are fetched (``pip download --no-deps``) and packed into
numbered parts ``.whl/1``, ``.whl/2``, ... of at most ``--part-mb`` (the device tool carries 64 MiB
a call, the working tree included). open3d's wheel alone is 100 MB: it travels as a 41 MB xz
tarball of what the pipeline imports (``slim_open3d``), so everything but pycolmap fits part 1;
a file still larger than a part is split across parts and joined again on the device. The end-to-end scene (``a-door`` from bench_end_to_end's cache,
or ``--scene-dir``) goes in the last part.

Then, with a GPU lent, one device call per part in order, each within the warm machine's idle
window of the one before (30 s), each running the same command::

    run(command="bash bench/gpu_check.sh", carry=[".whl/N"], timeout_s=540)

Each call stashes its part under ``.gpu_stash`` (ignored, kept on the warm machine) and runs what
the parts so far allow: gsplat's build and the rasterizer's GPU tests after part 1, the training
and rendering GPU tests once open3d is whole, the end-to-end benchmark after the last part. Its
logs and ``end_to_end_gpu.json`` come back under ``$OUT``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# What the project needs that the device image lacks (cp312 wheels; versions as the venv's).
WHEELS = [
    "gsplat==1.5.3", "jaxtyping", "wadler-lindig",
    "pydantic==2.14.4", "pydantic-core==2.50.5", "annotated-types", "typing-inspection",
    "zarr==3.1.6", "numcodecs==0.16.6", "donfig", "google-crc32c",
    "lzfse==0.4.2.post1", "openexr==3.5.3", "trimesh", "rtree==1.4.1",
    "addict", "pyquaternion", "configargparse",
    "open3d-cpu==0.19.0", "pycolmap==4.2.1",
]
PLATFORMS = ["manylinux_2_35_x86_64", "manylinux_2_31_x86_64", "manylinux_2_28_x86_64", "manylinux_2_27_x86_64",
             "manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux1_x86_64"]
LAST = ("pycolmap", "rtree")  # packed with the scene, in the last part (the benchmark needs pycolmap; rtree only the export)


def download(dest: Path) -> list[Path]:
    dest.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--python-version", "3.12",
           "--implementation", "cp", "-d", str(dest)]
    for p in PLATFORMS:
        cmd += ["--platform", p]
    subprocess.run(cmd + WHEELS, check=True)
    return sorted(dest.glob("*.whl"))


def slim_open3d(wheel: Path) -> Path:
    """open3d's wheel (100 MB, deflate) as an xz tarball of what the pipeline imports (~41 MB): its
    GUI's image-based-lighting maps and its torch ops are left out, and xz packs the 225 MB library
    far tighter than zip. ``gpu_check.sh`` unpacks it into the site folder (no pip: the wheel's
    RECORD no longer matches). So open3d and the small wheels fit one call instead of two."""
    out = wheel.with_name(wheel.name.split("-cp")[0] + ".tar.xz")
    if out.exists() and out.stat().st_mtime >= wheel.stat().st_mtime:
        return out
    with tempfile.TemporaryDirectory() as tmp:
        zipfile.ZipFile(wheel).extractall(tmp)
        skip = ("open3d/cpu/open3d_torch_ops.so", "open3d/examples", "open3d/labextension", "open3d/nbextension")

        def keep(info: tarfile.TarInfo) -> tarfile.TarInfo | None:
            name = info.name
            return None if name.startswith(skip) or name.endswith(".ktx") else info

        with tarfile.open(out, "w:xz", preset=6) as tar:
            for top in sorted(Path(tmp).iterdir()):
                if not top.name.endswith(".data"):
                    tar.add(top, arcname=top.name, filter=keep)
    return out


# The shared libraries open3d's pybind links that the device image lacks (its NEEDED entries: libGL,
# libX11, libudev; with what they link in turn). Debian's amd64 packages, fetched as the device
# README says; gpu_check.sh puts on LD_LIBRARY_PATH only those the image does not have.
SYSTEM_DEBS = ["libgl1", "libglx0", "libglvnd0", "libx11-6", "libxcb1", "libxau6", "libxdmcp6", "libbsd0", "libmd0",
               "libudev1", "libgomp1"]


def system_libs(dest: Path) -> Path | None:
    """``dest/syslibs.tar.xz``: the ``.so`` files of :data:`SYSTEM_DEBS` (about 1 MB), or None
    (with a note) where apt cannot fetch them here."""
    out = dest / "syslibs.tar.xz"
    if out.exists():
        return out
    with tempfile.TemporaryDirectory() as tmp:
        lists = Path(tmp) / "lists"
        (lists / "partial").mkdir(parents=True)
        opts = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
        try:
            subprocess.run(["apt-get", *opts, "update"], check=True, capture_output=True)
            subprocess.run(["apt-get", *opts, "download", *SYSTEM_DEBS], check=True, capture_output=True, cwd=tmp)
            root = Path(tmp) / "root"
            for deb in Path(tmp).glob("*.deb"):
                subprocess.run(["dpkg-deb", "-x", str(deb), str(root)], check=True)
        except (OSError, subprocess.CalledProcessError) as e:
            print(f"note: could not fetch {SYSTEM_DEBS} with apt ({e}); open3d will not import on the device")
            return None
        with tarfile.open(out, "w:xz", preset=9) as tar:
            for lib in sorted(root.rglob("*.so*")):
                tar.add(lib, arcname=lib.name)
    return out


def pack(files: list[Path], scene: Path | None, out: Path, part_bytes: int) -> list[Path]:
    """Greedy packing into ``out/1``, ``out/2``, ...; a file larger than the room left is split
    into ``NAME.part-K`` pieces (``gpu_check.sh`` joins them); ``manifest.json`` names every piece."""
    if out.exists():
        shutil.rmtree(out)
    first = [f for f in files if not f.name.lower().startswith(LAST)]
    last = [f for f in files if f.name.lower().startswith(LAST)]
    parts: list[list[tuple[str, bytes | Path]]] = [[]]
    room = part_bytes
    manifest: dict[str, list[str]] = {}

    def put(name: str, data: bytes | Path, size: int) -> None:
        nonlocal room
        if size > room:
            parts.append([])
            room = part_bytes
        parts[-1].append((name, data))
        room -= size

    for f in sorted(first, key=lambda f: f.stat().st_size):
        size = f.stat().st_size
        if size <= room:
            put(f.name, f, size)
            manifest[f.name] = [f.name]
            continue
        blob, k, pieces = f.read_bytes(), 0, []
        while blob:
            take = room if room > 1 << 20 else part_bytes
            piece, blob = blob[:take], blob[take:]
            name = f"{f.name}.part-{k:02d}"
            put(name, piece, len(piece))
            pieces.append(name)
            k += 1
        manifest[f.name] = pieces
    parts.append([])
    room = part_bytes
    for f in last:
        put(f.name, f, f.stat().st_size)
        manifest[f.name] = [f.name]
    dirs = []
    for i, items in enumerate(p for p in parts if p):
        d = out / str(i + 1)
        d.mkdir(parents=True)
        for name, data in items:
            if isinstance(data, Path):
                shutil.copy(data, d / name)
            else:
                (d / name).write_bytes(data)
        dirs.append(d)
    if scene is not None:
        shutil.copytree(scene, dirs[-1] / "scene")
    (dirs[-1] / "manifest.json").write_text(json.dumps({"parts": len(dirs), "files": manifest}, indent=2))
    for d in dirs[:-1]:
        (d / "manifest.json").write_text(json.dumps({"parts": len(dirs), "files": manifest}, indent=2))
    return dirs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene-dir", default=None, help="the end-to-end scene (default: bench_end_to_end's a-door)")
    ap.add_argument("--download-dir", default=str(ROOT / ".whl" / "download"))
    ap.add_argument("--part-mb", type=float, default=63.9,
                    help="largest part, MB (a call carries 64 MiB = 67.1 MB, the ~2.5 MB working tree included)")
    ap.add_argument("--no-download", action="store_true", help="pack what --download-dir already holds")
    args = ap.parse_args()
    dl = Path(args.download_dir)
    files = sorted(dl.glob("*.whl")) if args.no_download else download(dl)
    files = [slim_open3d(f) if f.name.startswith("open3d") else f for f in files]
    libs = system_libs(dl)
    files += [libs] if libs else []
    scene = Path(args.scene_dir) if args.scene_dir else None
    if scene is None:
        sys.path.insert(0, str(ROOT))
        from bench.bench_end_to_end import cache_root, ensure_scene

        scene = ensure_scene("a-door", cache_root(None))
    dirs = pack(files, scene, ROOT / ".whl" / "parts", int(args.part_mb * 1e6))
    for d in dirs:
        final = ROOT / ".whl" / d.name
        if final.exists():
            shutil.rmtree(final)
        d.rename(final)
        size = sum(f.stat().st_size for f in final.rglob("*") if f.is_file())
        print(f".whl/{d.name}: {size / 1e6:.1f} MB, {len(list(final.iterdir()))} entries")
    print("then, one device call per part, in order: run(command='bash bench/gpu_check.sh', carry=['.whl/N'])")


if __name__ == "__main__":
    main()
