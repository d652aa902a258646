"""Mesh reports as ``convert --report`` and ``check`` give them: printed, or
written as JSON or as the printed table, and exit code 4 when a check named by
``--require`` fails."""

from __future__ import annotations

import json
import sys

import typer

from ..errors import utf8_text
from .options import EXIT_CHECK_FAILED


def _report_result(result, target, required, examples, force, quiet) -> list[str]:
    """Check what ``result`` wrote, against its volume's grid; with
    post-processing, also the mesh as extracted, and say what changed.
    Returns the required checks that failed."""
    from ..report import check_mesh

    grid = result.summary.info.get("grid")
    checked = check_mesh(result.written, examples=examples, source=str(result.output), grid=grid)
    changed = bound = None
    if result.extracted is not None and not (quiet and target in (None, "-")):
        from ..post.pipeline import bound_lines, certified_bound, changes
        from ..writers.stored import stored_mesh

        # both as the file stores them (STL: three vertices per triangle)
        extracted = stored_mesh(result.extracted, result.format, result.ascii)
        before = check_mesh(extracted, examples=0, grid=grid).to_dict()
        changed = changes(before, checked.to_dict()) or ["nothing the report measures"]
        changed += bound_lines(result.summary.info)
        bound = certified_bound(result.summary.info)
        if not quiet:
            print(f"{result.output}: post-processing changed:", file=sys.stderr)
            for line in changed:
                print(f"  {line}", file=sys.stderr)
    try:
        _emit_report(
            checked, target, required, as_json=False, force=force, quiet=quiet, changed=changed,
            bound=bound,
        )  # fmt: skip
    except typer.Exit:
        return checked.failures(required)
    return []


def _emit_report(
    checked, target, required, *, as_json, force, quiet, changed=None, inputs=(), bound=None
) -> None:
    """Print the report (target "-") or write it to a file (JSON when its name ends in
    .json, else the printed table), with what post-processing ``changed`` (lines) in
    the file, and in JSON the decimation's certified ``bound`` as numbers; exit 4 when
    a required check fails."""
    from ..report import format_report

    if target is not None and target != "-":
        from ..atomic import atomic_output

        if str(target).lower().endswith(".json"):
            data = checked.to_dict()
            if changed is not None:
                data["post_processing"] = {"changed": list(changed)}
                if bound is not None:
                    data["post_processing"]["decimation"] = bound
            text = json.dumps(data, indent=2)
        else:
            text = format_report(checked)
            if changed is not None:
                text += "\n\npost-processing changed:\n" + "\n".join(f"  {c}" for c in changed)
        with atomic_output(target, force, "report.txt", inputs) as fh:
            fh.write(utf8_text(text + "\n"))
    elif target == "-" and not quiet:
        print(json.dumps(checked.to_dict(), indent=2) if as_json else format_report(checked))
    failed = checked.failures(required)
    if failed:
        print(
            f"isoconvert: {checked.source}: required check failed: {', '.join(failed)}",
            file=sys.stderr,
        )
        raise typer.Exit(EXIT_CHECK_FAILED)
