"""Writes the Python package osms as a wheel from a module cargo built (scripts/install-python
--wheel DIR runs it; the module is the one `./osms` and the editable install use, so nothing
is compiled again).

    python build-wheel.py LIB_NATIVE_SO OSMS_BIN OUT_DIR

The wheel holds crates/osms-py/python/osms, the module as osms/_native.abi3.so, the MuJoCo
library the module links (found through its RUNPATH; the module also searches its own
directory, crates/osms-py/build.rs) and the `osms` command (OSMS_BIN, the CLI built with the
module, without its debug sections) as a script, which pip installs into the environment's
bin/ (as ruff ships its binary; the binary finds the MuJoCo library in site-packages/osms/,
crates/osms/build.rs). So it installs into any CPython >= 3.9 on Linux x86_64 whatever is
checked out there, and `osms init`, `osms make` work from the wheel alone. Its bytes depend
only on its inputs (sorted entries, fixed times). Prints the wheel's path.
"""

import base64
import hashlib
import os
import re
import stat
import subprocess
import sys
import tempfile
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = os.path.join(ROOT, "crates", "osms-py", "python", "osms")
PYPROJECT = os.path.join(ROOT, "crates", "osms-py", "pyproject.toml")
CARGO = os.path.join(ROOT, "Cargo.toml")
TAG = "cp39-abi3-linux_x86_64"
EPOCH = (1980, 1, 1, 0, 0, 0)


def fail(message):
    print(f"error: {message}", file=sys.stderr)
    sys.exit(1)


def toml_string(text, key, where):
    m = re.search(rf'^{re.escape(key)}\s*=\s*"([^"]*)"', text, re.MULTILINE)
    if not m:
        fail(f"no `{key} = \"…\"` in {where}")
    return m.group(1)


def metadata():
    with open(PYPROJECT, encoding="utf-8") as f:
        project = f.read()
    with open(CARGO, encoding="utf-8") as f:
        cargo = f.read()
    deps = re.search(r"^dependencies\s*=\s*\[([^\]]*)\]", project, re.MULTILINE)
    if not deps:
        fail(f"no `dependencies = [...]` in {PYPROJECT}")
    return {
        # pyproject's version is dynamic: the crate's, i.e. the workspace's.
        "version": toml_string(cargo, "version", CARGO),
        "summary": toml_string(project, "description", PYPROJECT),
        "requires_python": toml_string(project, "requires-python", PYPROJECT),
        "license": toml_string(project, "license", PYPROJECT),
        "requires": re.findall(r'"([^"]+)"', deps.group(1)),
    }


def dynamic_section(lib):
    """The MuJoCo libraries `lib` needs and its RUNPATH directories."""
    try:
        dynamic = subprocess.run(["readelf", "-d", lib], check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        fail(f"cannot read {lib}'s dynamic section with readelf: {e}")
    needed = [n for n in re.findall(r"\(NEEDED\).*\[(.+)\]", dynamic) if n.startswith("libmujoco")]
    paths = [p for run in re.findall(r"\((?:RUNPATH|RPATH)\).*\[(.+)\]", dynamic) for p in run.split(":")]
    return needed, paths


def linked_mujoco(lib):
    """The MuJoCo library file `lib` needs, found in its RUNPATH."""
    needed, paths = dynamic_section(lib)
    if len(needed) != 1:
        fail(f"{lib} should link one MuJoCo library, it links {needed}")
    for directory in paths:
        candidate = os.path.join(directory, needed[0])
        if os.path.isfile(candidate):
            return needed[0], candidate
    fail(f"{needed[0]} is in none of {lib}'s RUNPATH directories {paths}\nhint: scripts/setup-mujoco")


def command(binary, soname):
    """The `osms` binary without its debug sections, after checking it links the same MuJoCo
    library and finds it beside the package once installed (site-packages/osms/)."""
    needed, paths = dynamic_section(binary)
    if needed != [soname]:
        fail(f"{binary} links {needed}, the module {soname}: build both in one cargo command")
    installed = f"$ORIGIN/../lib/python3.{sys.version_info.minor}/site-packages/osms"
    if installed not in paths:
        fail(f"{binary}'s RUNPATH lacks {installed} (crates/osms/build.rs): the installed command would not find MuJoCo")
    with tempfile.TemporaryDirectory() as tmp:
        stripped = os.path.join(tmp, "osms")
        try:
            subprocess.run(["objcopy", "--strip-debug", binary, stripped], check=True, capture_output=True)
        except (OSError, subprocess.CalledProcessError) as e:
            fail(f"cannot strip {binary} with objcopy: {e}")
        with open(stripped, "rb") as f:
            return f.read()


def record_line(name, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def main():
    if len(sys.argv) != 4:
        fail("usage: build-wheel.py LIB_NATIVE_SO OSMS_BIN OUT_DIR")
    lib, binary, out_dir = sys.argv[1], sys.argv[2], sys.argv[3]
    for path, what in ((lib, "module"), (binary, "osms binary")):
        if not os.path.isfile(path):
            fail(f"no {what} at {path}\nhint: scripts/install-python --wheel DIR builds it first")
    meta = metadata()
    files = {}
    for name in sorted(os.listdir(PACKAGE)):
        path = os.path.join(PACKAGE, name)
        if name.endswith((".py", ".pyi")) or name == "py.typed":
            with open(path, "rb") as f:
                files[f"osms/{name}"] = f.read()
    with open(lib, "rb") as f:
        files["osms/_native.abi3.so"] = f.read()
    soname, mujoco = linked_mujoco(lib)
    with open(mujoco, "rb") as f:
        files[f"osms/{soname}"] = f.read()
    files[f"osms-{meta['version']}.data/scripts/osms"] = command(binary, soname)
    dist = f"osms-{meta['version']}.dist-info"
    lines = [
        "Metadata-Version: 2.1",
        "Name: osms",
        f"Version: {meta['version']}",
        f"Summary: {meta['summary']}",
        f"License: {meta['license']}",
        f"Requires-Python: {meta['requires_python']}",
    ] + [f"Requires-Dist: {r}" for r in meta["requires"]]
    files[f"{dist}/METADATA"] = ("\n".join(lines) + "\n").encode()
    wheel_text = f"Wheel-Version: 1.0\nGenerator: osms scripts/build-wheel.py\nRoot-Is-Purelib: false\nTag: {TAG}\n"
    files[f"{dist}/WHEEL"] = wheel_text.encode()
    files[f"{dist}/top_level.txt"] = b"osms\n"
    record = [record_line(n, d) for n, d in files.items()] + [f"{dist}/RECORD,,"]
    files[f"{dist}/RECORD"] = ("\n".join(record) + "\n").encode()
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"osms-{meta['version']}-{TAG}.whl")
    tmp = path + ".partial"
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            info = zipfile.ZipInfo(name, date_time=EPOCH)
            executable = name.endswith(".so") or ".so." in name or "/scripts/" in name
            # pip marks a file executable only if its mode says it is a regular file.
            info.external_attr = (stat.S_IFREG | (0o755 if executable else 0o644)) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, data)
    os.replace(tmp, path)
    print(path)


if __name__ == "__main__":
    main()
