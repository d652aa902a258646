#!/usr/bin/env python
"""Take a screenshot of a Neuroglancer precomputed segmentation layer (as written by
``isoconvert convert ... --labels --format precomputed --with-volume``), entirely offline.

What to install (besides isoconvert itself):

    pip install neuroglancer pillow numpy      # neuroglancer 2.41.2 bundles the viewer's web client
    apt-get install -y chromium                # headless Chromium; WebGL comes from SwiftShader

Reproduce the README pictures from the volume (step 1 included; LAYER must not exist yet):

    python tools/neuroglancer_picture.py cochlea_layer neuroglancer_cochlea.png --4panel \
        --from-volume ../shared/datasets/bat-cochlea-volume.tif

which first runs

    isoconvert convert ../shared/datasets/bat-cochlea-volume.tif --labels \
        --format precomputed --with-volume --lods 3 -o cochlea_layer

or, for an existing layer:

    python tools/neuroglancer_picture.py LAYER_FOLDER OUT.png [--4panel]

What it does:
  1. serves LAYER_FOLDER on 127.0.0.1 (a small threaded HTTP server that sends
     ``Access-Control-Allow-Origin: *`` and answers HTTP ``Range`` requests with 206);
  2. starts a local neuroglancer Python viewer bound to 127.0.0.1, adds the folder as a
     segmentation layer ``precomputed://http://127.0.0.1:PORT``, selects every segment id
     that has a mesh (``mesh/<id>.index``), sets the layout and a camera that frames the volume;
  3. opens the viewer URL in headless Chromium (SwiftShader WebGL) and calls
     ``viewer.screenshot()`` (it needs that connected browser, and waits until every
     visible chunk and mesh fragment is loaded) for the 3d layout, and with --4panel
     again for the 4panel layout (voxels in the three cross sections, meshes in 3D);
  4. crops the uniform background away (3d only), shrinks the PNG with pillow (< 300 KB);
  5. stops Chromium, the viewer and the file server; prints every request the layer
     server saw (exit status 1 if any was not 2xx) and the browser's console lines.
"""

import argparse
import http.server
import io
import json
import os
import re
import shutil
import socketserver
import subprocess
import sys
import tempfile
import threading
import time

import neuroglancer
import numpy as np
from PIL import Image


# ---------------------------------------------------------------- file server
class _Handler(http.server.SimpleHTTPRequestHandler):
    log = []  # (method, path, status, range)

    def end_headers(self):
        self.send_header("Access-Control-Allow-Origin", "*")
        self.send_header("Access-Control-Allow-Headers", "Range")
        self.send_header("Access-Control-Expose-Headers", "Content-Range, Content-Length")
        self.send_header("Accept-Ranges", "bytes")
        super().end_headers()

    def do_OPTIONS(self):
        self.send_response(204)
        self.end_headers()

    def do_GET(self):
        rng = self.headers.get("Range")
        path = self.translate_path(self.path)
        if rng and os.path.isfile(path):
            m = re.fullmatch(r"bytes=(\d*)-(\d*)", rng.strip())
            size = os.path.getsize(path)
            if m and (m.group(1) or m.group(2)):
                if m.group(1):
                    start = int(m.group(1))
                    end = int(m.group(2)) if m.group(2) else size - 1
                else:  # suffix range
                    start, end = max(0, size - int(m.group(2))), size - 1
                end = min(end, size - 1)
                if start > end:
                    self.send_response(416)
                    self.send_header("Content-Range", f"bytes */{size}")
                    self.end_headers()
                    self.log.append(("GET", self.path, 416, rng))
                    return
                with open(path, "rb") as f:
                    f.seek(start)
                    body = f.read(end - start + 1)
                self.send_response(206)
                self.send_header("Content-Type", "application/octet-stream")
                self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
                self.log.append(("GET", self.path, 206, rng))
                return
        super().do_GET()

    def send_error(self, code, message=None, explain=None):
        self.log.append((self.command, self.path, code, self.headers.get("Range")))
        super().send_error(code, message, explain)

    def send_response(self, code, message=None):
        if code < 300 and self.command == "GET" and not self.headers.get("Range"):
            self.log.append(("GET", self.path, code, None))
        super().send_response(code, message)

    def log_message(self, *args):
        pass


class _Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True
    allow_reuse_address = True


def serve_folder(folder):
    handler = lambda *a, **k: _Handler(*a, directory=folder, **k)  # noqa: E731
    srv = _Server(("127.0.0.1", 0), handler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv, srv.server_address[1]


# ---------------------------------------------------------------- helpers
def segment_ids(folder):
    mesh_dir = os.path.join(folder, "mesh")
    ids = sorted(int(n[:-6]) for n in os.listdir(mesh_dir) if n.endswith(".index"))
    if not ids:  # legacy format: "<id>:0"
        ids = sorted(int(n[:-2]) for n in os.listdir(mesh_dir) if n.endswith(":0"))
    return ids


def crop_and_shrink(png_bytes, out, max_width, max_bytes=300_000, crop=True):
    img = Image.open(io.BytesIO(png_bytes)).convert("RGB")
    a = np.asarray(img).astype(int)
    bg = a[0, 0]
    diff = np.abs(a - bg).sum(axis=2) > 12
    ys, xs = np.nonzero(diff)
    if crop and len(xs):
        pad = 20
        box = (
            max(0, xs.min() - pad),
            max(0, ys.min() - pad),
            min(img.width, xs.max() + pad + 1),
            min(img.height, ys.max() + pad + 1),
        )
        img = img.crop(box)
    width = min(max_width, img.width)
    while True:
        im = (
            img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
            if width != img.width
            else img
        )
        buf = io.BytesIO()
        im.save(buf, "PNG", optimize=True)
        if buf.tell() <= max_bytes or width < 300:
            break
        width = int(width * 0.85)
    with open(out, "wb") as f:
        f.write(buf.getvalue())
    return im.size, buf.tell()


def find_chromium():
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    sys.exit("no chromium found: apt-get install -y chromium")


# ---------------------------------------------------------------- main
VIEWS = {
    # name: (layout, crop the background, max width of the PNG,
    #        3D view height as a multiple of the volume's diagonal)
    "3d": ("3d", True, 900, 0.63),
    "4panel": ("4panel", False, 1000, 1.0),
}


def take(viewer, size, timeout, stats):
    """viewer.screenshot() in a thread, so that a browser that never connects is a timeout."""
    done = threading.Event()
    box = {}

    def shoot():
        try:
            box["r"] = viewer.screenshot(size=size, statistics_callback=stats.append)
        except Exception as e:  # noqa: BLE001
            box["e"] = e
        done.set()

    threading.Thread(target=shoot, daemon=True).start()
    if not done.wait(timeout):
        raise SystemExit(f"no screenshot after {timeout} s (did Chromium connect? WebGL?)")
    if "e" in box:
        raise box["e"]
    return box["r"].screenshot


def main():
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    ap.add_argument("layer", help="precomputed layer folder (with info and mesh/)")
    ap.add_argument("out", help="output PNG (3D view); with --4panel also OUT_4panel.png")
    ap.add_argument(
        "--from-volume",
        metavar="VOLUME",
        help="first make LAYER with `isoconvert convert VOLUME --labels --format "
        "precomputed --with-volume --lods 3 -o LAYER` (LAYER must not exist)",
    )
    ap.add_argument(
        "--4panel",
        dest="four",
        action="store_true",
        help="also write OUT_4panel.png: cross sections (voxels) + 3D (meshes)",
    )
    ap.add_argument("--size", type=int, nargs=2, default=[1200, 800], help="canvas size")
    ap.add_argument("--zoom", type=float, default=1.0, help="3D zoom factor (>1: smaller object)")
    ap.add_argument(
        "--orientation",
        type=float,
        nargs=4,
        default=[0.33, -0.22, -0.08, 0.91],
        metavar=("X", "Y", "Z", "W"),
        help="3D orientation quaternion",
    )
    ap.add_argument("--background", default=None, help="3D background colour (default black)")
    ap.add_argument(
        "--show-slices",
        action="store_true",
        help="4panel: also draw the cross-section planes inside the 3D panel",
    )
    ap.add_argument(
        "--scale-bar",
        action="store_true",
        help="show scale bars (off by default: a volume without a unit is in '1 nm')",
    )
    ap.add_argument("--timeout", type=float, default=240)
    args = ap.parse_args()

    folder = os.path.abspath(args.layer)
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if args.from_volume:
        cmd = [
            "isoconvert",
            "convert",
            args.from_volume,
            "--labels",
            "--format",
            "precomputed",
            "--with-volume",
            "--lods",
            "3",
            "-o",
            folder,
        ]
        print("+", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)

    info = json.load(open(os.path.join(folder, "info")))
    scale = info["scales"][0]
    size = np.array(scale["size"], float)
    res = np.array(scale["resolution"], float)
    off = np.array(scale.get("voxel_offset", [0, 0, 0]), float)
    ids = segment_ids(folder)
    print(
        f"layer {folder}: size {size.astype(int).tolist()} resolution {res.tolist()} nm, "
        f"segments with meshes {ids}"
    )
    extent_nm = size * res

    srv, port = serve_folder(folder)
    neuroglancer.set_server_bind_address("127.0.0.1")
    viewer = neuroglancer.Viewer()
    source = f"precomputed://http://127.0.0.1:{port}"
    with viewer.txn() as s:
        s.dimensions = neuroglancer.CoordinateSpace(
            names=["x", "y", "z"], units="nm", scales=res.tolist()
        )
        s.layers["cochlea"] = neuroglancer.SegmentationLayer(source=source, segments=ids)
        s.position = (off + size / 2).tolist()  # voxel coordinates: the volume's centre
        s.show_axis_lines = False
        s.show_scale_bar = args.scale_bar
        s.show_slices = args.show_slices
        if args.background:
            s.projection_background_color = args.background
        s.projection_orientation = args.orientation
        s.cross_section_scale = 2.2 * float(extent_nm.max()) / min(args.size)  # nm per pixel
    url = viewer.get_viewer_url()
    print("viewer:", url, "  layer source:", source)

    prof = tempfile.mkdtemp(prefix=".ngshot-chrome-", dir=out_dir)
    log_path = os.path.splitext(os.path.abspath(args.out))[0] + ".chromium.log"
    log_f = open(log_path, "w")
    cmd = [
        find_chromium(),
        "--headless=new",
        "--no-sandbox",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist",
        "--disable-dev-shm-usage",
        "--no-first-run",
        "--no-default-browser-check",
        f"--user-data-dir={prof}",
        f"--window-size={args.size[0]},{args.size[1] + 100}",
        "--enable-logging=stderr",
        "--v=0",
        url,
    ]
    proc = subprocess.Popen(cmd, stdout=log_f, stderr=subprocess.STDOUT)
    try:
        jobs = [("3d", args.out)]
        if args.four:
            jobs.append(("4panel", os.path.splitext(args.out)[0] + "_4panel.png"))
        for view, out in jobs:
            layout, crop, max_width, height = VIEWS[view]
            with viewer.txn() as s:
                s.layout = layout
                # projection_scale: the height of the 3D view in world units (nm)
                s.projection_scale = height * float(np.linalg.norm(extent_nm)) * args.zoom
                s.show_default_annotations = layout != "3d"  # the volume's bounding box
            t0 = time.time()
            stats = []
            shot = take(viewer, args.size, args.timeout, stats)
            total = stats[-1].total if stats else None
            loaded = ""
            if total is not None:
                shown = f"{total.visible_chunks_gpu_memory}/{total.visible_chunks_total}"
                loaded = f", visible chunks {shown} on the GPU"
            print(
                f"{view}: screenshot {shot.width}x{shot.height} in {time.time() - t0:.1f} s{loaded}"
            )
            (w, h), nbytes = crop_and_shrink(shot.image, out, max_width, crop=crop)
            print(f"wrote {out}: {w}x{h}, {nbytes:,} bytes")
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log_f.close()
        srv.shutdown()
        srv.server_close()
        neuroglancer.stop()
        shutil.rmtree(prof, ignore_errors=True)

    log = _Handler.log
    bad = [r for r in log if r[2] >= 300]
    print(
        f"layer server: {len(log)} requests, {sum(1 for r in log if r[2] == 206)} range "
        f"requests (206), {len(bad)} not OK"
    )
    for r in log:
        print("   ", "NOT OK" if r[2] >= 300 else "ok", r[0], r[1], int(r[2]), r[3] or "")
    console = [
        ln.rstrip()
        for ln in open(log_path, errors="replace")
        if "CONSOLE" in ln or ("ERROR" in ln and "dbus" not in ln)
    ]
    print(f"browser console / errors ({log_path}):")
    for ln in console:
        print("   ", ln[:400])
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
