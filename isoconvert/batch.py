"""Many volumes at once: discovery, scheduling over worker processes, summary.

The library reports progress through a callback and never prints; the CLI
draws the progress bar and the table.
"""

from __future__ import annotations

import csv
import fnmatch
import glob as globlib
import io
import json
import os
import time
import tomllib
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .errors import InputNotFoundError, IsoconvertError
from .readers import READERS
from .readers.tiff import TIFF_SUFFIXES, natural_key

#: Bytes of working memory a conversion needs per byte of samples (a native-order
#: or NaN-free copy at most, vertex and triangle arrays, the writer's records),
#: plus a fixed part for the interpreter and numba.
MEMORY_FACTOR = 3
MEMORY_BASE = 300 * 2**20


@dataclass
class Found:
    """A volume found in the inputs: what to read and the name to mirror."""

    spec: str  # a file, or a folder of TIFF slices
    relative: Path  # its path relative to the input it was found under
    size: int  # bytes of samples, roughly, for scheduling


@dataclass
class Skipped:
    path: str
    reason: str


@dataclass
class Job:
    """One conversion to run."""

    input: str
    output: str
    level: float | str
    options: dict = field(default_factory=dict)  # read options and flip
    estimate: int = 0  # bytes of memory it is expected to need


@dataclass
class Outcome:
    """What happened to one input (a row of the summary)."""

    input: str
    output: str
    status: str  # ok, failed, check-failed, skipped, interrupted
    level: float | None = None
    vertices: int | None = None
    cells: int | None = None
    seconds: float = 0.0
    checks: dict | None = None
    message: str = ""


# --- discovery --------------------------------------------------------------------------


def discover(
    inputs: list[str], recursive: bool = False, exclude: Path | None = None
) -> tuple[list[Found], list[Skipped]]:
    """Find the volumes in files, folders and globs.

    A folder holding only single-image TIFF slices of one shape is one volume
    (a stack); a ``.nhdr`` header and the data files it names count once;
    files of unknown formats are skipped with a reason. Symbolic links to
    folders are followed once (a loop is cut where it closes). ``exclude`` (the
    output folder) is never searched.
    """
    found: list[Found] = []
    skipped: list[Skipped] = []
    excluded = exclude.resolve() if exclude else None
    for spec in inputs:
        path = Path(spec)
        if path.is_file():
            _add_files([path], path.parent, found, skipped)
        elif path.is_dir():
            _walk(path, recursive, excluded, found, skipped)
        elif globlib.has_magic(spec):
            matches = sorted(
                globlib.glob(spec, recursive=recursive), key=lambda p: natural_key(Path(p))
            )
            if not matches:
                raise InputNotFoundError(f"{spec}: the pattern matches nothing")
            files = [Path(m) for m in matches if Path(m).is_file()]
            root = Path(os.path.commonpath([str(Path(m).parent) for m in matches]))
            _add_files(files, root, found, skipped)
            for m in matches:
                if Path(m).is_dir():
                    _walk(Path(m), recursive, excluded, found, skipped)
        else:
            raise InputNotFoundError(f"{spec}: no such file, folder or pattern")
    return found, skipped


def _walk(root: Path, recursive: bool, excluded, found, skipped) -> None:
    seen: set[str] = set()
    for folder, dirs, files in os.walk(root, followlinks=True):
        real = os.path.realpath(folder)
        if real in seen or (excluded and Path(real) == excluded):
            dirs[:] = []
            if real in seen:
                skipped.append(Skipped(folder, "a link back to a folder already searched"))
            continue
        seen.add(real)
        dirs.sort(key=lambda d: natural_key(Path(d)))
        if not recursive:
            dirs[:] = []
        paths = sorted((Path(folder) / f for f in files), key=natural_key)
        stack = _tiff_stack(paths)
        if stack:
            rel = Path(folder).relative_to(root)
            name = rel if str(rel) != "." else Path(root.resolve().name)
            found.append(Found(folder, name, sum(p.stat().st_size for p in stack)))
            paths = [p for p in paths if p not in stack]
        _add_files(paths, root, found, skipped)


def _tiff_stack(paths: list[Path]) -> list[Path]:
    """The TIFF files of a folder when they are 2+ single images of one shape."""
    tiffs = [p for p in paths if p.suffix.lower() in TIFF_SUFFIXES]
    if len(tiffs) < 2:
        return []
    import tifffile

    shapes = set()
    try:
        for p in tiffs:
            with tifffile.TiffFile(p) as tif:
                if len(tif.pages) != 1:
                    return []
                page = tif.pages[0]
                shapes.add((page.shape, str(page.dtype)))
    except Exception:  # an unreadable TIFF: let each file fail on its own
        return []
    return tiffs if len(shapes) == 1 else []


def _add_files(paths: list[Path], root: Path, found, skipped) -> None:
    # data files named by a detached header beside them are read through it
    consumed: dict[Path, Path] = {}
    for folder in {p.parent for p in paths}:
        for header in folder.glob("*.nhdr"):
            consumed.update({data: header for data in _nhdr_data_files(header)})
    for p in paths:
        header = consumed.get(p.resolve())
        if header is not None:
            if header.resolve() not in {q.resolve() for q in paths}:
                skipped.append(Skipped(str(p), f"the data of {header.name}; convert that header"))
            continue
        match = READERS.by_suffix(p.suffix)
        if match is None:
            skipped.append(Skipped(str(p), "not a volume format isoconvert reads"))
            continue
        try:
            rel = p.relative_to(root)
        except ValueError:
            rel = Path(p.name)
        found.append(Found(str(p), rel, _sample_bytes(p)))


def _nhdr_data_files(header: Path) -> set[Path]:
    """Files a detached NRRD header names as its data (one file or a numbered set)."""
    try:
        import nrrd

        value = str(nrrd.read_header(str(header)).get("data file", ""))
    except Exception:
        return set()
    from .readers.nrrd import _MULTI_FILE

    multi = _MULTI_FILE.match(value)
    if multi:
        fmt, lo, hi, step = (
            multi.group(1),
            int(multi.group(2)),
            int(multi.group(3)),
            int(multi.group(4)),
        )
        if step == 0:
            return set()
        names = [fmt % n for n in range(lo, hi + (1 if step > 0 else -1), step)]
    else:
        names = [value] if value and not value.startswith("LIST") else []
    return {(header.parent / n).resolve() for n in names}


def _sample_bytes(path: Path) -> int:
    """Rough in-memory size of a file's samples, for scheduling."""
    size = path.stat().st_size
    suffix = path.suffix.lower()
    if suffix in (".nrrd", ".nhdr"):
        try:
            import nrrd
            import numpy as np

            header = nrrd.read_header(str(path))
            from nrrd.reader import _determine_datatype

            item = _determine_datatype({**header, "endian": "little"}).itemsize
            return int(np.prod([int(s) for s in header["sizes"]], dtype=np.float64)) * item
        except Exception:
            return size
    if suffix in (".png", ".jpg", ".jpeg", ".bmp", ".gif"):
        return 8 * size  # compressed
    return size


# --- levels and per-file options ------------------------------------------------------------

_OPTION_KEYS = ("shape", "dtype", "endian", "header_bytes", "channel", "spacing", "origin", "flip")


@dataclass
class Rule:
    """One entry of a level mapping: a path pattern and what applies to matches."""

    pattern: str
    level: float | str | None = None
    options: dict = field(default_factory=dict)

    def matches(self, relative: Path) -> bool:
        posix = relative.as_posix()
        return fnmatch.fnmatch(posix, self.pattern) or fnmatch.fnmatch(relative.name, self.pattern)


def read_mapping(path: str | Path) -> list[Rule]:
    """Rules from a TOML (``[[volume]]`` tables) or CSV (a header row) file.

    Keys: ``pattern`` (required; matched against the path relative to its
    input, or the file name), ``level`` (number or "auto"), and the read
    options ``shape``, ``dtype``, ``endian``, ``header_bytes``, ``channel``,
    ``spacing``, ``origin``, plus ``flip``. In CSV, several numbers go in one
    cell separated by spaces or ``x`` ("256x256x128").
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(f"{path}: no such level mapping file")
    text = path.read_text(encoding="utf-8")
    try:
        if path.suffix.lower() == ".toml":
            rows = tomllib.loads(text).get("volume", [])
        elif path.suffix.lower() == ".csv":
            rows = [
                {k.strip(): v.strip() for k, v in r.items() if k and v and v.strip()}
                for r in csv.DictReader(io.StringIO(text))
            ]
        else:
            raise IsoconvertError(f"{path}: a level mapping is a .toml or .csv file")
    except (tomllib.TOMLDecodeError, csv.Error) as exc:
        raise IsoconvertError(f"{path}: not a readable level mapping ({exc})") from None
    rules = []
    for n, row in enumerate(rows, start=1):
        if not isinstance(row, dict) or "pattern" not in row:
            raise IsoconvertError(f"{path}: entry {n} has no 'pattern'")
        unknown = set(row) - {"pattern", "level", *_OPTION_KEYS}
        if unknown:
            raise IsoconvertError(
                f"{path}: entry {n} has unknown key(s) {', '.join(sorted(unknown))}; "
                f"known: pattern, level, {', '.join(_OPTION_KEYS)}"
            )
        options = {k: _parse_option(k, row[k], path, n) for k in _OPTION_KEYS if k in row}
        level = row.get("level")
        if isinstance(level, str) and level.strip().lower() != "auto":
            level = _parse_option("level", level, path, n)
        rules.append(Rule(str(row["pattern"]), level, options))
    return rules


def _parse_option(key: str, value, path: Path, n: int):
    try:
        if key in ("shape", "spacing", "origin"):
            parts = (
                value.replace("x", " ").replace(",", " ").split()
                if isinstance(value, str)
                else value
            )
            kind = int if key == "shape" else float
            return tuple(kind(p) for p in parts)
        if key in ("header_bytes", "channel"):
            return int(value)
        if key == "level":
            return float(value)
        if key == "flip":
            return value if isinstance(value, bool) else str(value).lower() in ("1", "true", "yes")
        return str(value)
    except (TypeError, ValueError):
        raise IsoconvertError(f"{path}: entry {n}: bad value {value!r} for {key}") from None


# --- planning ---------------------------------------------------------------------------------


def plan(
    found: list[Found],
    out_dir: Path,
    suffix: str,
    level: float | str | None,
    rules: list[Rule] | None = None,
    skip_existing: bool = False,
    force: bool = False,
    options: dict | None = None,
    raw_options: dict | None = None,
) -> tuple[list[Job], list[Outcome]]:
    """Jobs for the found volumes; outcomes for those skipped because done.

    ``options`` (e.g. spacing) apply to every file, ``raw_options`` (shape,
    dtype, endian, header bytes) to raw files only; a mapping entry overrides both.

    Output names mirror the input paths under ``out_dir`` with ``suffix``. Two
    inputs that would give the same name (``a.nrrd`` and ``a.tif``) keep their
    input suffix in it (``a.nrrd.ply``, ``a.tif.ply``).
    """
    names = [
        f.relative.with_suffix(suffix) if f.relative.suffix else Path(str(f.relative) + suffix)
        for f in found
    ]
    clashes = {n for n in names if names.count(n) > 1}
    jobs, done = [], []
    for f, name in zip(found, names, strict=True):
        if name in clashes:
            name = Path(str(f.relative) + suffix)
        output = out_dir / name
        rule = next((r for r in rules or [] if r.matches(f.relative)), None)
        job_level = rule.level if rule and rule.level is not None else level
        reader = READERS.by_suffix(Path(f.spec).suffix)
        is_raw = reader is not None and reader[0] == "raw"
        job_options = {
            **(options or {}),
            **((raw_options or {}) if is_raw else {}),
            **(rule.options if rule else {}),
        }
        if job_level is None:
            done.append(
                Outcome(
                    f.spec,
                    str(output),
                    "failed",
                    message=f"{f.spec}: no level; give --level or a mapping entry",
                )
            )
            continue
        if output.exists() and skip_existing:
            done.append(Outcome(f.spec, str(output), "skipped", message="output exists"))
            continue
        if output.exists() and not force:
            done.append(
                Outcome(
                    f.spec,
                    str(output),
                    "failed",
                    message=f"{output}: already exists; pass --force or --skip-existing",
                )
            )
            continue
        estimate = MEMORY_FACTOR * f.size + MEMORY_BASE
        jobs.append(Job(f.spec, str(output), job_level, job_options, estimate))
    return jobs, done


# --- running ------------------------------------------------------------------------------------


def run_one(job: Job, settings: dict) -> Outcome:
    """Convert one volume; every failure becomes an outcome, never an exception.

    ``settings`` holds what applies to all files: convert() keyword arguments
    and ``require`` (check names).
    """
    from .convert import convert
    from .report import check_mesh

    start = time.perf_counter()

    def failed(message: str) -> Outcome:
        return Outcome(
            job.input, job.output, "failed", seconds=time.perf_counter() - start, message=message
        )

    options = dict(job.options)
    flip = options.pop("flip", settings.get("flip", False))
    require = settings.get("require") or []
    kwargs = {k: v for k, v in settings.items() if k not in ("require", "flip")}
    try:
        Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        result = convert(
            job.input, job.output, job.level, flip=flip, force=True, **kwargs, **options
        )
    except IsoconvertError as exc:
        return failed(str(exc))
    except MemoryError:
        return failed(f"{job.input}: out of memory; convert it alone or lower --jobs")
    except Exception as exc:  # a bug: report it for this file, keep the others going
        return failed(f"{job.input}: internal error {type(exc).__name__}: {exc}")
    mesh = result.mesh
    outcome = Outcome(
        job.input,
        job.output,
        "ok",
        level=float(mesh.info["level"]),
        vertices=mesh.n_vertices,
        cells=mesh.n_cells,
    )
    if require:
        report = check_mesh(mesh, source=job.output)
        outcome.checks = {name: report.checks[name] for name in require}
        failed = report.failures(require)
        if failed:
            outcome.status = "check-failed"
            outcome.message = f"{job.output}: required check failed: {', '.join(failed)}"
    outcome.seconds = time.perf_counter() - start
    return outcome


def _run_one_dict(job: dict, settings: dict) -> dict:
    """Pickle-friendly wrapper for worker processes."""
    return asdict(run_one(Job(**job), settings))


def run_jobs(
    jobs: list[Job],
    settings: dict,
    workers: int = 1,
    max_memory: int | None = None,
    on_done: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Run the jobs, ``workers`` at a time, within ``max_memory`` bytes of estimates.

    A job whose estimate alone exceeds the budget runs with nothing else beside
    it. One failure never stops the others: a worker that dies (killed, out of
    memory) breaks the pool, so each job that was running is run again alone,
    which fails only the one that kills its worker; the pool then starts again
    for the rest. On
    KeyboardInterrupt, jobs not finished are reported as interrupted (their
    outputs are written atomically, so none is left half-written).
    """
    outcomes: list[Outcome] = []

    def done(outcome: Outcome) -> None:
        outcomes.append(outcome)
        if on_done:
            on_done(outcome)

    if workers <= 1:
        for n, job in enumerate(jobs):
            try:
                done(run_one(job, settings))
            except KeyboardInterrupt:
                for rest in jobs[n:]:
                    done(Outcome(rest.input, rest.output, "interrupted", message="interrupted"))
                raise
        return outcomes

    import multiprocessing

    budget = max_memory or (1 << 62)
    pending = list(jobs)
    context = multiprocessing.get_context("spawn")  # no fork of a threaded parent
    while pending:
        running: dict = {}
        used = 0
        try:
            with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
                while pending or running:
                    while pending and len(running) < workers:
                        job = pending[0]
                        if running and used + job.estimate > budget:
                            break
                        pending.pop(0)
                        running[pool.submit(_run_one_dict, asdict(job), settings)] = job
                        used += job.estimate
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for future in finished:
                        job = running[future]  # stays there if the pool broke: retried alone
                        try:
                            result = Outcome(**future.result())
                        except BrokenProcessPool:
                            raise
                        except Exception as exc:
                            result = Outcome(
                                job.input,
                                job.output,
                                "failed",
                                message=f"{job.input}: {type(exc).__name__}: {exc}",
                            )
                        del running[future]
                        used -= job.estimate
                        done(result)
        except BrokenProcessPool:
            # A dead worker breaks the whole pool, and with it the jobs beside it.
            # Run each of those alone: only the one that kills its worker fails.
            for job in running.values():
                done(_run_alone(job, settings, context))
        except KeyboardInterrupt:
            for job in [*running.values(), *pending]:
                done(Outcome(job.input, job.output, "interrupted", message="interrupted"))
            raise
    return outcomes


def _run_alone(job: Job, settings: dict, context) -> Outcome:
    """Run one job in a worker of its own; a worker that dies fails only this job."""
    try:
        with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
            return Outcome(**pool.submit(_run_one_dict, asdict(job), settings).result())
    except BrokenProcessPool:
        return Outcome(
            job.input,
            job.output,
            "failed",
            message=f"{job.input}: the worker process died (out of memory?); "
            "convert it alone or lower --jobs",
        )


# --- summary ----------------------------------------------------------------------------------

SUMMARY_FIELDS = (
    "input",
    "output",
    "status",
    "level",
    "vertices",
    "cells",
    "seconds",
    "checks",
    "message",
)


def summary_bytes(outcomes: list[Outcome], suffix: str) -> bytes:
    """The summary as JSON (``.json``) or CSV (``.csv``)."""
    rows = [asdict(o) for o in outcomes]
    if suffix == ".json":
        totals = {
            s: sum(o.status == s for o in outcomes)
            for s in ("ok", "failed", "check-failed", "skipped", "interrupted")
        }
        return (json.dumps({"files": rows, "totals": totals}, indent=2) + "\n").encode("utf-8")
    if suffix == ".csv":
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=SUMMARY_FIELDS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            row["checks"] = ";".join(
                f"{k}={'pass' if v else 'fail'}" for k, v in (row["checks"] or {}).items()
            )
            writer.writerow(row)
        return out.getvalue().encode("utf-8")
    raise IsoconvertError(f"--summary takes a .json or .csv file name, got {suffix or 'none'}")
