"""Dask distributed as the engine of block-wise extraction and batch (issue 10).

The meshes made on a cluster are the in-memory ones, bit for bit; failures
(no scheduler, a worker that dies, an error inside a task) are one-line
``IsoconvertError``\\ s and leave no output file.
"""

from __future__ import annotations

import functools
import os
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import cloudpickle  # noqa: E402  (comes with distributed)
import dask  # noqa: E402
from conftest import dataset, read_real_scan, real_scan_names, small_tmpfs  # noqa: E402

import isoconvert.distributed as dd  # noqa: E402
from isoconvert import (  # noqa: E402
    batch,  # noqa: E402
    extract,
    read_volume,
)
from isoconvert.convert import ConvertOptions, convert  # noqa: E402
from isoconvert.errors import IsoconvertError, OutputError, VolumeError  # noqa: E402
from isoconvert.extract.blocks import Blocks, slab_ranges  # noqa: E402
from isoconvert.grid import LazyGrid  # noqa: E402
from isoconvert.volume import Volume  # noqa: E402

# A scheduler serves HTTP (health checks) on port 8787 even without a dashboard,
# and says so when another one has it.
pytestmark = pytest.mark.filterwarnings("ignore:Port 8787 is already in use")

# The task wrappers below are sent to workers that cannot import this module.
cloudpickle.register_pickle_by_value(sys.modules[__name__])


# --- fixtures ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cluster():
    """Two single-thread worker processes (with nannies, which restart dead ones).

    One death per task is allowed (Dask's default is three): the tests of dying
    workers then take two deaths, not four.
    """
    from distributed import LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        local = LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        )
    yield local
    dd.close_clients()
    local.close()


@pytest.fixture
def address(cluster) -> str:
    """The LocalCluster's address, once both of its workers are up (a test that
    killed one leaves its nanny restarting it)."""
    dd.connect(cluster.scheduler_address).wait_for_workers(2, timeout=30)
    return cluster.scheduler_address


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def dask_processes(tmp_path_factory):
    """A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1,
    started in a folder of their own (so relative paths would not work there)."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    home = tmp_path_factory.mktemp("dask-home")
    env = dict(os.environ)
    env.pop(dd.SCHEDULER_ENV, None)
    common = {"cwd": home, "env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    dask_cli = [sys.executable, "-m", "dask"]
    processes = [
        subprocess.Popen(
            [*dask_cli, "scheduler", "--host", "127.0.0.1", "--port", str(port)]
            + ["--no-dashboard", "--dashboard-address", "127.0.0.1:0"],  # no port 8787
            **common,
        )
    ]
    try:
        for _ in range(2):
            processes.append(
                subprocess.Popen(
                    [*dask_cli, "worker", address, "--nthreads", "1", "--no-dashboard"]
                    + ["--host", "127.0.0.1"],
                    **common,
                )
            )
        client = dd.connect(address, timeout=30)
        client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        dd.close_clients()
        # the workers first: a worker whose scheduler is gone waits to reconnect
        for group in (processes[1:], processes[:1]):
            for p in group:
                p.terminate()
            for p in group:
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


def _field(shape=(13, 11, 17), seed=0) -> Volume:
    data = np.random.default_rng(seed).random(shape, dtype=np.float32)
    return Volume(data, spacing=(0.5, 1.25, 2.0), origin=(-3.0, 1.5, 7.0))


def _same(a, b) -> None:
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert np.array_equal(a.cells, b.cells)
    assert np.array_equal(a.edge_ids, b.edge_ids)


def _write_raw(folder: Path, data_xyz: np.ndarray, stem: str = "vol") -> Path:
    """``data_xyz`` (X, Y, Z) as ``stem_XxYxZ_dtype.raw`` (x fastest)."""
    dims = "x".join(map(str, data_xyz.shape))
    path = folder / f"{stem}_{dims}_{data_xyz.dtype.name}.raw"
    path.write_bytes(np.ascontiguousarray(data_xyz.T).tobytes())
    return path


def _ball_raw(folder: Path, n=(24, 22, 20), stem="ball", radius=7.0) -> Path:
    x, y, z = np.meshgrid(*(np.arange(k, dtype=float) for k in n), indexing="ij")
    c = [(k - 1) / 2 for k in n]
    r = np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2)
    data = np.clip(200 - 20 * (r - radius), 0, 255).astype(np.uint8)
    return _write_raw(folder, data, stem)


def _with_task(monkeypatch, task) -> list:
    """Make extract_blocks' runners run ``task`` on the workers; returns the
    sources the runners were made for."""
    made = []
    original = dd.dask_runner

    def runner(address, source, name, task_=None, **kw):
        made.append(source)
        return original(address, source, name, task, **kw)

    monkeypatch.setattr(dd, "dask_runner", runner)
    return made


def _cli(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    full_env = {**os.environ, **(env or {})}
    full_env.pop(dd.SCHEDULER_ENV, None)
    return subprocess.run(
        [sys.executable, "-m", "isoconvert", *map(str, args)],
        capture_output=True,
        text=True,
        env=full_env,
        cwd=cwd,
        timeout=120,
    )


# --- task wrappers (run on the workers) ------------------------------------------------------


def _expects(kind, job, samples):
    """The default task, after checking who read the slab."""
    if not isinstance(samples, kind):
        raise AssertionError(f"the task got {type(samples).__name__}, not {kind.__name__}")
    return dd.extract_slab(job, samples)


def _dies_once(marker: str, job, samples):
    """Kill the worker process the first time any slab runs (the marker file
    decides); the slab is then run again by another worker."""
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return dd.extract_slab(job, samples)
    os._exit(1)


def _always_dies(job, samples):
    os._exit(1)


# --- the same mesh on a cluster --------------------------------------------------------------


@pytest.mark.parametrize(
    "method, options",
    [
        ("cubes", {}),
        ("cubes", {"ambiguity": "trilinear"}),
        ("tetra", {}),
        ("squares", {"axis": "z"}),
        ("squares", {"axis": "x"}),
    ],
    ids=["cubes", "cubes-trilinear", "tetra", "squares-z", "squares-x"],
)
def test_cluster_mesh_is_the_in_memory_mesh(address, monkeypatch, method, options):
    volume = _field()
    reference = extract(volume, 0.5, method=method, **options)
    sources = _with_task(monkeypatch, functools.partial(_expects, np.ndarray))
    for size in (1, 3, 5):  # 5 does not divide 17 layers
        mesh = extract(
            volume, 0.5, method=method, blocks=Blocks(size=size, scheduler=address), **options
        )
        _same(mesh, reference)
        assert mesh.info["blocks"] == len(slab_ranges(17, size))
    assert all(isinstance(s, np.ndarray) for s in sources)  # read here, sent with the tasks


def test_samples_equal_to_the_level_restart_on_the_cluster(cluster, address, monkeypatch):
    data = np.random.default_rng(3).integers(0, 5, size=(12, 10, 14)).astype(np.uint8)
    data[data == 2] = 1
    data[5, 5, 12] = 2  # the only sample equal to the level, in the last slab (x, y, z)
    volume = Volume(data, spacing=(1.0, 0.5, 2.0), origin=(1.0, 2.0, 3.0))
    reference = extract(volume, 2)
    calls = []
    original = dd.dask_runner

    def counting(*args, **kw):
        run = original(*args, **kw)

        def counted(jobs):
            calls.append(jobs[0].offset)
            return run(jobs)

        return counted

    monkeypatch.setattr(dd, "dask_runner", counting)
    mesh = extract(volume, 2, blocks=Blocks(size=3, scheduler=address))
    _same(mesh, reference)
    assert mesh.info.get("vertex_offset") == reference.info.get("vertex_offset")
    assert calls[0] == 0 and len(calls) == 2 and calls[1] > 0  # restarted with the offset
    # equal samples in every slab: each chooses the offset, no second pass
    calls.clear()
    data = np.random.default_rng(3).integers(0, 5, size=(12, 10, 14)).astype(np.uint8)
    volume = Volume(data)
    _same(extract(volume, 2, blocks=Blocks(size=3, scheduler=address)), extract(volume, 2))
    assert len(calls) == 1
    # the slabs of the abandoned first pass were cancelled, not left to run
    deadline = time.monotonic() + 10
    while any(str(key).startswith("isoconvert-slab") for key in cluster.scheduler.tasks):
        assert time.monotonic() < deadline, list(cluster.scheduler.tasks)
        time.sleep(0.05)


@pytest.mark.parametrize("name", real_scan_names())
def test_every_real_scan_on_the_cluster_is_the_in_memory_mesh(address, name):
    """Raw, NRRD (raw and gzip), TIFF and headsq's numbered files, each read as
    the reader gives it (worker-side or client-side slabs)."""
    from isoconvert.stats import histogram, otsu_level

    volume = read_real_scan(name)
    level = otsu_level(histogram(volume.samples))
    slabs = max(2, volume.shape[2] // 5)  # about five tasks
    _same(
        extract(volume, level, blocks=Blocks(size=slabs, scheduler=address)), extract(volume, level)
    )


def test_trilinear_on_the_cluster_is_the_in_memory_mesh_of_a_real_scan(address):
    """The Marschner-Lobb signal, whose cubes need interior vertices at this level."""
    from isoconvert.extract.trilinear import inner_base

    dataset("marschner_lobb_41x41x41_uint8.raw")
    volume = read_real_scan("marschner_lobb_41x41x41_uint8.raw")
    reference = extract(volume, 128.5, ambiguity="trilinear")
    assert (reference.edge_ids >= inner_base(volume.shape)).sum() > 100
    for size in (4, 9):
        mesh = extract(
            volume, 128.5, ambiguity="trilinear", blocks=Blocks(size=size, scheduler=address)
        )
        _same(mesh, reference)


def test_workers_read_their_own_slabs_of_a_real_scan(address, monkeypatch):
    path = dataset("tooth_103x94x161_uint8.raw")
    monkeypatch.chdir(path.parent)  # a relative path here; the workers' folder is another
    volume = read_volume(path.name)
    assert volume.grid is not None and not volume.grid.sequential
    reference = extract(volume, 90)  # in memory: smaller than the default budget
    sources = _with_task(monkeypatch, functools.partial(_expects, LazyGrid))
    mesh = extract(volume, 90, blocks=Blocks(size=40, scheduler=address))
    _same(mesh, reference)
    assert mesh.info["blocks"] == 4
    assert sources and all(isinstance(s, LazyGrid) for s in sources)
    assert dd._worker_side(volume.grid).path.is_absolute()


def _slow_first(job, samples):
    """The first slab finishes last."""
    if job.k0 == 0:
        time.sleep(1.0)
    return dd.extract_slab(job, samples)


def test_results_come_in_order_and_the_window_is_bounded(address, monkeypatch):
    from isoconvert.extract.blocks import BlockJob
    from isoconvert.extract.tables import DEFAULT_AMBIGUITY

    volume = _field(shape=(9, 8, 25), seed=6)
    template = BlockJob(
        method="cubes",
        level=0.5,
        k0=0,
        k1=0,
        offset=0.0,
        ambiguity=DEFAULT_AMBIGUITY,
        axis="z",
        reverse=False,
        nan_as=None,
        affine=np.eye(3),
        origin=np.zeros(3),
        grid_shape=volume.shape,
        threads=1,
        source="field",
    )
    jobs = [replace(template, k0=k0, k1=k1) for k0, k1 in slab_ranges(25, 2)]
    submitted = []
    submit = dd._submit

    def counting(client, task, args):  # the runner's private _submit (issue 21)
        submitted.append(args[0].k0)
        return submit(client, task, args)

    monkeypatch.setattr(dd, "_submit", counting)
    for max_bytes, window in ((None, 4), (1, 2)):  # 2 threads; 1 byte: two slabs at most
        submitted.clear()
        runner = dd.dask_runner(address, volume.samples, "field", _slow_first, max_bytes=max_bytes)
        order = []
        for n, result in enumerate(runner(jobs)):
            order.append(result.k0)
            assert len(submitted) <= n + window
        assert order == [job.k0 for job in jobs] == submitted


# --- failures ------------------------------------------------------------------------------------


def test_an_error_inside_a_task_reaches_the_caller(address):
    volume = _field(seed=4)
    volume.data[3, 4, 9] = np.nan
    with pytest.raises(VolumeError) as here:
        extract(volume, 0.5, blocks=Blocks(size=4))
    with pytest.raises(VolumeError) as there:
        extract(volume, 0.5, blocks=Blocks(size=4, scheduler=address))
    assert type(there.value) is type(here.value)
    assert str(there.value) == str(here.value)
    assert "NaN" in str(there.value) and "\n" not in str(there.value)


def test_task_errors_survive_pickling():
    import pickle

    plain = dd.TaskFailure.of(VolumeError("v.raw: NaN; pass --nan-as"))
    assert type(plain.error) is VolumeError and str(plain.error) == "v.raw: NaN; pass --nan-as"
    custom = batch.NoVolumesError(["in"], [])  # its constructor takes other arguments
    sent = pickle.loads(pickle.dumps(dd.TaskFailure.of(custom)))
    assert isinstance(sent.error, IsoconvertError) and str(sent.error) == str(custom)


def _closed_address() -> str:
    return f"tcp://127.0.0.1:{_free_port()}"


def test_no_scheduler_is_one_line_in_time(monkeypatch):
    monkeypatch.setenv(dd.TIMEOUT_ENV, "1")
    address = _closed_address()
    start = time.perf_counter()
    with pytest.raises(IsoconvertError) as caught:
        extract(_field(), 0.5, blocks=Blocks(scheduler=address))
    assert time.perf_counter() - start < 6
    message = str(caught.value)
    assert "\n" not in message and address in message and "dask scheduler" in message
    with pytest.raises(IsoconvertError, match="not a Dask scheduler address"):
        dd.connect("nonsense://somewhere", timeout=1)
    monkeypatch.setenv(dd.TIMEOUT_ENV, "soon")
    with pytest.raises(IsoconvertError, match=dd.TIMEOUT_ENV):
        dd.connect(address)


def test_a_scheduler_without_workers_is_one_line(monkeypatch, tmp_path):
    from distributed import LocalCluster

    monkeypatch.setenv(dd.TIMEOUT_ENV, "1")
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as empty:
        start = time.perf_counter()
        with pytest.raises(IsoconvertError, match="no worker for 1 s") as caught:
            extract(_field(), 0.5, blocks=Blocks(size=4, scheduler=empty.scheduler_address))
        assert time.perf_counter() - start < 8
        assert "\n" not in str(caught.value) and "dask worker" in str(caught.value)
        volume = _ball_raw(tmp_path)
        settings = batch.BatchSettings(scheduler=empty.scheduler_address)
        jobs = [batch.Job(str(volume), str(tmp_path / "out" / "a.ply"), 100)]
        (outcome,) = batch.run_jobs(jobs, settings)
        assert outcome.status == "failed" and "no worker" in outcome.message
        assert not (tmp_path / "out").exists()  # the folder made for it is gone again
        dd.close_clients()


def test_no_scheduler_cli(tmp_path):
    volume = _ball_raw(tmp_path)
    out = tmp_path / "out.ply"
    run = _cli(
        "convert",
        volume,
        "-o",
        out,
        "--level",
        100,
        "--scheduler",
        _closed_address(),
        env={dd.TIMEOUT_ENV: "1"},
    )
    assert run.returncode != 0
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1, run.stderr
    assert "no Dask scheduler answered" in lines[0] and "Traceback" not in run.stderr
    assert not out.exists() and run.stdout == ""


def test_scheduler_address_option_env():
    assert dd.scheduler_address("tcp://a:1") == "tcp://a:1"
    env = os.environ.pop(dd.SCHEDULER_ENV, None)
    try:
        assert dd.scheduler_address(None) is None
        os.environ[dd.SCHEDULER_ENV] = "tcp://b:2"
        assert dd.scheduler_address(None) == "tcp://b:2"
        assert dd.scheduler_address("tcp://a:1") == "tcp://a:1"
    finally:
        os.environ.pop(dd.SCHEDULER_ENV, None)
        if env is not None:
            os.environ[dd.SCHEDULER_ENV] = env


# --- a real scheduler and workers, through the CLI and the API ------------------------------


def test_cli_convert_on_a_cluster_is_byte_identical(dask_processes, tmp_path):
    volume = _ball_raw(tmp_path)
    here = _cli("convert", volume.name, "-o", "b.ply", "--level", 100, cwd=tmp_path)
    assert here.returncode == 0, here.stderr
    there = _cli(
        "convert",
        volume.name,  # relative: the workers run elsewhere
        "-o",
        "a.ply",
        "--level",
        100,
        "--block-size",
        6,
        "--scheduler",
        dask_processes,
        cwd=tmp_path,
    )
    assert there.returncode == 0, there.stderr
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()

    api = tmp_path / "c.ply"
    options = ConvertOptions(blocks=Blocks(size=7, scheduler=dask_processes))
    convert(volume, api, 100, options)
    plain = tmp_path / "d.ply"
    convert(volume, plain, 100)
    assert api.read_bytes() == plain.read_bytes()


def test_batch_on_a_cluster_is_byte_identical(dask_processes, tmp_path):
    inputs = tmp_path / "in"
    inputs.mkdir()
    files = [
        _ball_raw(inputs, n=(16 + i, 18, 14 + 2 * i), stem=f"b{i}", radius=5 + i) for i in range(3)
    ]
    here = _cli("batch", *files, "-o", tmp_path / "here", "--level", 100, "--jobs", 1, "-q")
    assert here.returncode == 0, here.stderr
    there = _cli(
        "batch", *files, "-o", tmp_path / "there", "--level", 100, "-q",
        "--scheduler", dask_processes,
    )  # fmt: skip
    assert there.returncode == 0, there.stderr
    names = sorted(p.name for p in (tmp_path / "here").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "there").iterdir())
    assert len(names) == 3
    for name in names:
        assert (tmp_path / "there" / name).read_bytes() == (tmp_path / "here" / name).read_bytes()


def test_batch_layers_on_a_cluster_are_byte_identical(dask_processes, tmp_path):
    """batch --format precomputed with --scheduler: each volume's layer written by a
    worker process, the same folder as here."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    for i in range(2):
        np.save(inputs / f"a{i}.npy", _atlas(seed=4 + i))
    layer = ["--labels", "--format", "precomputed", "--lods", "2", "-q"]
    here = _cli("batch", inputs, "-o", tmp_path / "here", "--jobs", 1, *layer)
    assert here.returncode == 0, here.stderr
    there = _cli("batch", inputs, "-o", tmp_path / "there", "--scheduler", dask_processes, *layer)
    assert there.returncode == 0, there.stderr

    def files(folder: Path) -> dict[str, bytes]:
        return {
            str(f.relative_to(folder)): f.read_bytes() for f in folder.rglob("*") if f.is_file()
        }

    made = files(tmp_path / "here")
    assert {"a0/info", "a1/info", "a0/mesh/info"} <= set(made)
    assert files(tmp_path / "there") == made


def _atlas(shape=(20, 18, 40), cells=6, seed=4) -> np.ndarray:
    """(Z, Y, X) uint16 labels: nearest of a few random seeds, background outside a ball."""
    rng = np.random.default_rng(seed)
    points = np.stack(np.meshgrid(*(np.arange(n) for n in shape), indexing="ij"), -1)
    seeds = rng.uniform(0, shape, size=(cells, 3))
    nearest = np.argmin(((points[..., None, :] - seeds) ** 2).sum(-1), axis=-1) + 1
    centre = (np.array(shape) - 1) / 2
    inside = (((points - centre) / (np.array(shape) / 2)) ** 2).sum(-1) < 1
    return np.where(inside, nearest, 0).astype(np.uint16)


def test_label_surfaces_on_the_cluster_are_the_in_memory_ones(address):
    from isoconvert.extract.labels import label_surfaces

    volume = Volume(_atlas().T, spacing=(0.5, 1.0, 1.5), direction=np.diag([1.0, 1.0, -1.0]))
    reference = label_surfaces(volume, smoothing=5)
    got = label_surfaces(volume, smoothing=5, blocks=Blocks(size=4, scheduler=address))
    assert got.labels == reference.labels
    assert got.combined.vertices.tobytes() == reference.combined.vertices.tobytes()
    assert np.array_equal(got.combined.cells, reference.combined.cells)
    for label in reference.labels:
        assert got[label].vertices.tobytes() == reference[label].vertices.tobytes()
        assert np.array_equal(got[label].cells, reference[label].cells)


def test_cli_label_layer_on_a_cluster_is_byte_identical(dask_processes, tmp_path):
    """A Neuroglancer layer (meshes, two levels of detail, the voxels) of a label
    volume: the same bytes in memory, slab by slab here, and on the cluster,
    where the workers read their own slabs of the file."""
    pytest.importorskip("DracoPy")
    pytest.importorskip("meshoptimizer")
    np.save(tmp_path / "atlas.npy", _atlas())
    runs = {"memory": [], "slabs": ["--block-size", 7], "cluster": ["--scheduler", dask_processes]}
    for name, extra in runs.items():
        run = _cli(
            "convert", "atlas.npy", "--labels", "-o", name, "--format", "precomputed",
            "--lods", 2, "--with-volume", *extra, cwd=tmp_path,
        )  # fmt: skip
        assert run.returncode == 0, run.stderr
    files = {
        name: {str(p.relative_to(tmp_path / name)): p.read_bytes()
               for p in (tmp_path / name).rglob("*") if p.is_file()}
        for name in runs
    }  # fmt: skip
    assert len([f for f in files["memory"] if f.endswith(".index")]) == 6
    assert files["slabs"] == files["memory"]
    assert files["cluster"] == files["memory"]


def _encode_and_sign(marker: str, function, *args):
    """A layer's object task that notes the process it ran in, and what it sent
    back of the object's fragment data: its size (the task wrote it) or the bytes."""
    from isoconvert.convert import _object_task

    result = _object_task(function, *args)
    with open(marker, "a") as f:
        f.write(f"{os.getpid()} {type(result[1]).__name__}\n")
    return result


def _encode_elsewhere(function, target, *args):
    """A layer's object task on a worker that does not see the client's folder."""
    from isoconvert.convert import _object_task

    return _object_task(function, "/nonexistent-isoconvert-folder/1", *args)


def _fail_third(function, target, *args):
    """The third object fails, once the others may have written their fragments."""
    from isoconvert.convert import _object_task

    if target.endswith("/3"):
        time.sleep(0.5)
        raise IsoconvertError("object 3 refused on the worker")
    return _object_task(function, target, *args)


def _refuse_object(function, *args):
    raise IsoconvertError("object refused on the worker")


def _layer_files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("sharded", [False, True])
def test_layer_objects_are_encoded_and_written_by_the_workers(
    address, monkeypatch, tmp_path, sharded
):
    """With a scheduler, each object's levels of detail are decimated and encoded
    by a worker (not here), which writes the fragments into the layer's part folder
    itself and sends back only the manifest; the layer is the one written here,
    byte for byte; an error inside such a task is the run's one-line error, and no
    layer is left."""
    pytest.importorskip("DracoPy")
    pytest.importorskip("meshoptimizer")
    from isoconvert.label_convert import convert_labels

    convert_module = sys.modules["isoconvert.convert"]  # the package's `convert` is the function

    np.save(tmp_path / "atlas.npy", _atlas())
    options = {"format": "precomputed", "lods": 2, "force": True, "sharded": sharded}
    convert_labels(tmp_path / "atlas.npy", tmp_path / "here", **options)
    marker = tmp_path / "pids"
    monkeypatch.setattr(
        convert_module, "_object_task", functools.partial(_encode_and_sign, str(marker))
    )
    blocks = Blocks(scheduler=address)
    convert_labels(tmp_path / "atlas.npy", tmp_path / "there", blocks=blocks, **options)
    signs = [line.split() for line in marker.read_text().splitlines()]
    assert len(signs) == 6  # one task per label ...
    assert {int(pid) for pid, _ in signs} and os.getpid() not in {int(p) for p, _ in signs}
    assert {sent for _, sent in signs} == {"int"}  # ... which wrote its fragments itself
    assert _layer_files(tmp_path / "there") == _layer_files(tmp_path / "here")
    # a worker that does not see the folder sends the fragments back: the same layer
    monkeypatch.setattr(convert_module, "_object_task", _encode_elsewhere)
    convert_labels(tmp_path / "atlas.npy", tmp_path / "sent", blocks=blocks, **options)
    assert _layer_files(tmp_path / "sent") == _layer_files(tmp_path / "here")
    # one object failing while the others write theirs: nothing is left
    monkeypatch.setattr(convert_module, "_object_task", _fail_third)
    with pytest.raises(IsoconvertError, match="^object 3 refused on the worker$"):
        convert_labels(tmp_path / "atlas.npy", tmp_path / "failed", blocks=blocks, **options)
    time.sleep(1.0)  # the other objects' tasks have ended: they wrote nothing afterwards
    assert not (tmp_path / "failed").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".failed")]
    monkeypatch.setattr(convert_module, "_object_task", _refuse_object)
    with pytest.raises(IsoconvertError, match="^object refused on the worker$"):
        convert_labels(tmp_path / "atlas.npy", tmp_path / "failed", blocks=blocks, **options)
    assert not (tmp_path / "failed").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".failed")]


def _note_encoder(marker: str, function, *args):
    """A layer's task that notes which encoder it ran, how many triangles it got
    (an object put together from rows: how many rows' tasks' fragments, each a
    dict), and (rows') the object's box they are rows of and how many rows."""
    from isoconvert.convert import _object_task

    encoder = getattr(args[2], "__name__", "an object's arrays")
    box = args[7].lo.tolist() if encoder == "encode_rows" else None
    rows = len(args[8]) if encoder == "encode_rows" else 0
    if encoder == "assemble_object":
        assert all(isinstance(row, dict) for row in args[3])
    count = len(args[3] if encoder == "assemble_object" else args[4])
    with open(marker, "a") as f:
        f.write(f"{encoder};{count};{box};{rows}\n")
    return _object_task(function, *args)


@pytest.mark.parametrize(("sharded", "grouped"), [(False, False), (True, True)])
def test_one_cut_level_is_encoded_on_the_workers_rows_of_fragments_per_task(
    address, monkeypatch, tmp_path, sharded, grouped
):
    """With a scheduler, a label layer of one level cut into fragments: each task
    is one row of one label's fragments (ROW_TRIANGLES 0), or neighbouring rows
    of one z-layer (by default, these labels being small), made of the triangles
    reaching them (no task gets a whole label, and the client builds none), then
    one task a label is given its rows' fragments (from the workers) and writes
    it, and the layer is the one written here, byte for byte."""
    pytest.importorskip("DracoPy")
    from isoconvert.extract.labels import LabelMeshes, label_surfaces
    from isoconvert.label_convert import convert_labels
    from isoconvert.writers.precomputed import tasks as layer_tasks

    convert_module = sys.modules["isoconvert.convert"]
    if not grouped:
        monkeypatch.setattr(layer_tasks, "ROW_TRIANGLES", 0)  # a row a task
    np.save(tmp_path / "atlas.npy", _atlas())
    options = {"format": "precomputed", "lods": 1, "fragment_size": 4.0, "sharded": sharded}
    convert_labels(tmp_path / "atlas.npy", tmp_path / "here", **options)
    whole = label_surfaces(Volume(_atlas()))
    triangles = {label: whole[label].n_cells for label in whole.labels}
    marker = tmp_path / "tasks"
    monkeypatch.setattr(
        convert_module, "_object_task", functools.partial(_note_encoder, str(marker))
    )
    built = []
    real = LabelMeshes._build
    monkeypatch.setattr(LabelMeshes, "_build", lambda self, n: built.append(n) or real(self, n))
    blocks = Blocks(scheduler=address)
    convert_labels(tmp_path / "atlas.npy", tmp_path / "there", blocks=blocks, **options)
    assert built == []
    tasks = [line.split(";") for line in marker.read_text().splitlines()]
    assert {encoder for encoder, *_ in tasks} == {"encode_rows", "assemble_object"}
    rows: dict[str, list[int]] = {}  # each label's rows' tasks' triangles, labels in order
    for _, n, box, _ in (task for task in tasks if task[0] == "encode_rows"):
        rows.setdefault(box, []).append(int(n))
    in_task = [int(n) for encoder, *_, n in tasks if encoder == "encode_rows"]
    assert max(in_task) > 1 if grouped else max(in_task) == 1
    assembled = [int(n) for encoder, n, *_ in tasks if encoder == "assemble_object"]
    assert len(rows) == len(triangles) and assembled == [len(r) for r in rows.values()]
    for (label, count), taken in zip(triangles.items(), rows.values(), strict=True):
        # several rows, none with every triangle, each triangle in one at least
        assert len(taken) > 1 and max(taken) < count <= sum(taken), label
    assert _layer_files(tmp_path / "there") == _layer_files(tmp_path / "here")


def _sum_of(values: list) -> float:
    return float(sum(v.sum() for v in values))


def _earlier_run(address: str, tasks: list) -> list:
    from isoconvert.runner import run_in_order

    return list(run_in_order(address, tasks, budget=1 << 30, died=lambda task: "died"))


def test_a_kept_tasks_value_goes_to_the_task_that_names_it_not_here(address):
    """Tasks kept for a later one's Earlier argument: None comes back in their
    place, the later task gets their values (arrays made on the workers) in the
    order it names them, and a key taken twice is refused."""
    from isoconvert.runner import Earlier, Task

    tasks = [
        Task(np.full, ((1000,), 1.0), key="kept-a", kept=True),
        Task(np.full, ((10,), 3.0), key="kept-b", kept=True),
        Task(np.arange, (4,), key="plain"),
        Task(_sum_of, (Earlier(("kept-b", "kept-a")),), key="sum"),
    ]
    values = _earlier_run(address, tasks)
    assert values[:2] == [None, None] and values[2].tolist() == [0, 1, 2, 3]
    assert values[3] == 1000.0 + 30.0
    again = [Task(np.ones, (3,), key="kept-c", kept=True)]
    again += [Task(_sum_of, (Earlier(("kept-c",)),), key=f"twice-{n}") for n in range(2)]
    with pytest.raises(KeyError):
        _earlier_run(address, again)


def _refusing_collapse(mesh, bound, locked=None):
    """A collapse that refuses a slab (one with locked vertices) as a user's error."""
    if locked is not None:
        raise IsoconvertError("the slab's collapse refused it")
    return np.asarray(mesh.cells)


def test_a_slabs_error_on_the_cluster_is_its_one_line_and_nothing_is_written(
    address, monkeypatch, tmp_path
):
    """A large object's slab that fails with a user's error on a worker: its
    message from the task of the coarser levels it was kept for, no folder left."""
    pytest.importorskip("DracoPy")
    import trimesh

    from isoconvert.convert import layer_objects_on
    from isoconvert.mesh import Mesh
    from isoconvert.writers.precomputed import tasks as precomputed
    from isoconvert.writers.precomputed import write_precomputed

    monkeypatch.setattr(precomputed, "LARGE_OBJECT", 1000)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=20.0)
    meshes = {1: Mesh(sphere.vertices + 30.0, sphere.faces.astype(np.int64))}
    grid = {"shape": (64, 64, 64), "origin": (0.0, 0.0, 0.0), "affine": np.eye(3)}
    on_cluster = layer_objects_on(ConvertOptions(blocks=Blocks(scheduler=address)), "ball")
    with pytest.raises(IsoconvertError, match="^the slab's collapse refused it$"):
        write_precomputed(
            tmp_path / "layer", meshes, grid, lods=2, collapse=_refusing_collapse,
            map_objects=on_cluster,
        )  # fmt: skip
    assert list(tmp_path.iterdir()) == []


def _note_coarse(marker: str, function, *args):
    """A layer's task that notes its encoder and, for a large object's coarser
    levels, how many slabs' collapses it was given (each a tuple, here)."""
    from isoconvert.convert import _object_task

    encoder = getattr(args[2], "func", args[2])
    given = args[3] if encoder.__name__ == "_coarse_fragments" else ()
    assert all(isinstance(slab, tuple) for slab in given)
    with open(marker, "a") as f:
        f.write(f"{encoder.__name__};{len(given)}\n")
    return _object_task(function, *args)


@pytest.mark.parametrize("fragments", [4.0, None])
def test_large_objects_coarser_levels_are_the_same_in_memory_in_slabs_and_on_the_cluster(
    address, monkeypatch, tmp_path, fragments
):
    """Objects above LARGE_OBJECT triangles get their coarser levels from slabs of
    their surface (the others whole), cut into fragments or not: the same layer in
    memory, read in slabs, and on the cluster (whose workers collapse the slabs,
    make level 0, a row at a time when it is cut, and the coarser levels from the
    slabs' collapses, one task an object, which the client neither makes nor sees)."""
    pytest.importorskip("DracoPy")
    pytest.importorskip("meshoptimizer")
    from isoconvert.label_convert import convert_labels
    from isoconvert.writers.precomputed import tasks as precomputed

    monkeypatch.setattr(precomputed, "LARGE_OBJECT", 1000)
    monkeypatch.setattr(precomputed, "SLAB_TRIANGLES", 600)
    slabbed = []
    real = precomputed._coarse_levels
    monkeypatch.setattr(
        precomputed, "_coarse_levels", lambda s, *a: slabbed.append(len(s)) or real(s, *a)
    )
    np.save(tmp_path / "atlas.npy", _atlas())
    options = {"format": "precomputed", "lods": 2, "fragment_size": fragments}
    runs = {"memory": Blocks(), "slabs": Blocks(size=7), "cluster": Blocks(scheduler=address)}
    marker = tmp_path / "tasks"
    convert_module = sys.modules["isoconvert.convert"]
    for name, blocks in runs.items():
        if name == "cluster":
            monkeypatch.setattr(
                convert_module, "_object_task", functools.partial(_note_coarse, str(marker))
            )
        convert_labels(tmp_path / "atlas.npy", tmp_path / name, blocks=blocks, **options)
    # the 6 labels: 340 to 3,788 triangles, 4 of them above 1,000, in 2 to 7 slabs,
    # their coarser levels made here in memory and in slabs, by a worker on the cluster
    assert len(slabbed) == 2 * 4 and min(slabbed) >= 2
    there = [line.split(";") for line in marker.read_text().splitlines()]
    coarse = [int(n) for name, n in there if name == "_coarse_fragments"]
    assert coarse == slabbed[:4]
    assert sum(name == "collapse_slab" for name, _ in there) == sum(coarse)
    assert _layer_files(tmp_path / "slabs") == _layer_files(tmp_path / "memory")
    assert _layer_files(tmp_path / "cluster") == _layer_files(tmp_path / "memory")


def test_a_full_disk_while_the_workers_write_fragments_is_one_line(address, tmp_path):
    """A layer of 1.9 MB of fragments onto a 1 MiB tmpfs, its objects written by the
    workers: the one-line disk-full error naming the layer, and the tmpfs empty."""
    pytest.importorskip("DracoPy")
    import trimesh

    from isoconvert.convert import layer_objects_on
    from isoconvert.mesh import Mesh
    from isoconvert.writers.precomputed import encode_object, write_object, write_precomputed

    rng = np.random.default_rng(3)
    meshes = {}
    for segment in range(1, 41):  # bumpy spheres: Draco cannot shrink their positions much
        sphere = trimesh.creation.icosphere(subdivisions=5, radius=20.0)
        bumps = sphere.vertices + rng.normal(0, 0.3, sphere.vertices.shape) + 30 * segment
        meshes[segment] = Mesh(bumps, sphere.faces.astype(np.int64))
    grid = {"shape": (1300, 1300, 1300), "origin": (0.0, 0.0, 0.0), "affine": np.eye(3)}
    on_cluster = layer_objects_on(ConvertOptions(blocks=Blocks(scheduler=address)), "bumps")
    write_precomputed(tmp_path / "roomy", meshes, grid, map_objects=on_cluster)
    assert sum(p.stat().st_size for p in (tmp_path / "roomy").rglob("*")) > 1.5 * 2**20
    with small_tmpfs(tmp_path / "full", "1m") as disk:
        with pytest.raises(OutputError, match="disk full at") as caught:
            write_precomputed(disk / "layer", meshes, grid, map_objects=on_cluster)
        message = str(caught.value)
        # the workers' fragments fill it, and one of them or the client's next
        # manifest is the write that fails
        assert "\n" not in message and str(disk / "layer") in message
        assert list(disk.iterdir()) == []
        # a worker's own write that finds no room says so
        (disk / "part").mkdir()
        mesh = meshes[1]
        args = (mesh.vertices, mesh.cells, np.zeros(3), np.eye(3), 1, 16, None, None)
        (disk / "filler").write_bytes(b"x" * (2**20 - 8192))
        with pytest.raises(OutputError, match="while a worker wrote an object") as caught:
            write_object(str(disk / "part" / "1"), "the-layer", encode_object, *args)
        assert str(caught.value).startswith("disk full at the-layer")


# --- workers that die (last: the LocalCluster's nannies restart them) ------------------------


def test_a_worker_that_dies_once_changes_nothing(address, monkeypatch, tmp_path):
    volume = _field(shape=(15, 12, 19), seed=5)
    reference = extract(volume, 0.5)
    marker = tmp_path / "died"
    _with_task(monkeypatch, functools.partial(_dies_once, str(marker)))
    mesh = extract(volume, 0.5, blocks=Blocks(size=3, scheduler=address))
    assert marker.exists()  # a worker did die
    _same(mesh, reference)


def test_workers_that_keep_dying_fail_in_one_line(address, monkeypatch, tmp_path):
    volume = _ball_raw(tmp_path)
    output = tmp_path / "out.ply"
    _with_task(monkeypatch, _always_dies)
    options = ConvertOptions(blocks=Blocks(size=4, scheduler=address))
    with pytest.raises(IsoconvertError) as caught:
        convert(volume, output, 100, options)
    message = str(caught.value)
    assert "\n" not in message
    assert "worker died while extracting z-layers" in message and "nothing was written" in message
    assert not output.exists()
    assert list(tmp_path.iterdir()) == [volume]
