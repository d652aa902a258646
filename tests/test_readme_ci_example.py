"""The README's CI example runs as written on the bundled sample volumes."""

from __future__ import annotations

import json
import shlex
import shutil

from conftest import ROOT, SAMPLES

from isoconvert.cli import main


def readme_ci_command() -> list[str]:
    """The `isoconvert batch ...` step of the README's GitHub Actions example."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = text.split("### In CI", 1)[1].split("```yaml", 1)[1].split("```", 1)[0]
    lines = block.splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "- run: >")
    indent = len(lines[start]) - len(lines[start].lstrip())
    step = []
    for line in lines[start + 1 :]:  # the folded scalar: lines indented deeper
        if len(line) - len(line.lstrip()) <= indent:
            break
        step.append(line.strip())
    words = shlex.split(" ".join(step))
    assert words[:2] == ["isoconvert", "batch"]
    return words[1:]


def test_the_ci_example_passes_on_the_samples(tmp_path, monkeypatch, capsys):
    shutil.copytree(SAMPLES, tmp_path / "sample_volumes")
    monkeypatch.chdir(tmp_path)
    args = readme_ci_command()
    assert main(args) == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "meshes" / "summary.json").read_text())
    rows = summary if isinstance(summary, list) else summary["files"]
    statuses = {row["status"] for row in rows}
    assert statuses <= {"ok", "skipped"} and "ok" in statuses
    assert len(list((tmp_path / "meshes").glob("*.ply"))) == 9
