"""Option values without pydantic (isoconvert.cli.coercion): the same values, and the
same errors, as typer's own pydantic adapters, and a convert run imports no pydantic."""

from __future__ import annotations

import subprocess
import sys
from enum import Enum
from pathlib import Path

import pytest
import typer
import typer.main
from conftest import SAMPLES

from isoconvert.cli import app, coercion

pytestmark = pytest.mark.skipif(
    coercion.RuntimeParam is None, reason="this typer coerces without pydantic adapters"
)

#: Values a command line (or a default) may hand each kind of parameter: plain ones the
#: fast coercion decides, and odd ones it must leave to typer's adapter.
SAMPLES_BY_TYPE = {
    str: ["", "x", "atlas.npy", " 12 ", "auto", "1,2,3", 0, None],
    int: [
        0,
        7,
        -3,
        "0",
        "12",
        "-4",
        "+5",
        "007",
        " 8",
        "1_000",
        "1.0",
        "1e3",
        "abc",
        "",
        "123456789012345678901234",
        2.0,
        True,
    ],  # fmt: skip
    float: [
        0,
        0.5,
        3,
        "1",
        "-2.5",
        ".5",
        "5.",
        "1e3",
        "1E-2",
        "+7",
        " 1",
        "1_0",
        "nan",
        "inf",
        "1e400",
        "abc",
        "",
        "0x10",
        True,
    ],  # fmt: skip
    bool: [True, False, "true", "no", 1],
    Path: ["out.ply", "", "-", "/dev/null", ".", str(SAMPLES), Path("x.ply"), 3],
}


def _commands():
    command = typer.main.get_command(app)
    yield command
    yield from command.commands.values()


def _plain_params():
    for command in _commands():
        for param in command.params:
            if isinstance(getattr(param, "_runtime_param", None), coercion.PlainRuntimeParam):
                yield command.name, param


def _outcome(runtime, value, param):
    try:
        return "value", runtime._coerce_value(value, param=param, ctx=None)
    except typer.BadParameter as exc:
        return "error", exc.format_message()


def _values(annotation):
    many = getattr(annotation, "__origin__", None) is list
    leaf = annotation.__args__[0] if many else annotation
    if isinstance(leaf, type) and issubclass(leaf, Enum):
        values = [*leaf, *(m.value for m in leaf), "nope", "", 1]
        values += [m.value.upper() for m in leaf]
    else:
        values = SAMPLES_BY_TYPE[leaf]
    return [tuple(values[:3]), list(values), "one", ()] if many else values


def test_every_plain_parameter_of_every_command_is_covered():
    params = list(_plain_params())
    assert len(params) > 100  # convert, batch, info, check ... all get it
    kinds = {p.type_descriptor.annotation for _, p in params}
    assert {str, int, float, Path} <= kinds


@pytest.mark.parametrize("command, param", list(_plain_params()),
                         ids=lambda x: x if isinstance(x, str) else x.name)  # fmt: skip
def test_same_values_and_errors_as_typer(command, param):
    from typer._coercion import build_runtime_param

    own = build_runtime_param(param.type_descriptor)
    assert not isinstance(own, coercion.PlainRuntimeParam)
    for value in _values(param.type_descriptor.annotation):
        fast = _outcome(param._runtime_param, value, param)
        slow = _outcome(own, value, param)
        assert repr(fast) == repr(slow), (command, param.name, value)  # nan == nan
        assert type(fast[1]) is type(slow[1]), (command, param.name, value)


def test_bad_number_on_the_command_line_says_what_typer_says(tmp_path, capsys):
    from isoconvert.cli import main

    code = main(["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(tmp_path / "s.ply"),
                 "--level", "100", "--header-bytes", "many"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "--header-bytes" in err and "integer" in err, err
    assert not (tmp_path / "s.ply").exists()


def test_a_conversion_imports_no_pydantic(tmp_path):
    out = tmp_path / "s.ply"
    script = (
        "import sys\n"
        "from isoconvert.cli import main\n"
        f"code = main(['convert', {str(SAMPLES / 'sphere_40x40x40_uint8.raw')!r},\n"
        f"             '-o', {str(out)!r}, '--level', '100', '-q', '--shape', '40', '40',\n"
        "             '40', '--dtype', 'uint8', '--endian', 'little', '--header-bytes', '0',\n"
        "             '--spacing', '1', '1', '1', '--smooth', '2', '--max-memory', '1G'])\n"
        "assert code == 0, code\n"
        "print('pydantic' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False"]
    assert out.exists()
