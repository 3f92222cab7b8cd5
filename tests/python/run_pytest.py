"""ctest's entry to the pytest suite of the `reflcap` Python module (test_reflcap.py).

Runs pytest on this folder. Exits 77 (ctest's SKIP_RETURN_CODE) with the reason when the suite
cannot run here at all: pytest or NumPy missing from this interpreter, or no module built for its
version in REFLCAP_PYTHON_DIR (a build carried to another machine as executables only, say
../shared/tools/gpu-bundle.sh's, holds no Python module). Everything else is the suite's to judge.
"""
import glob
import importlib.util
import os
import sys

SKIP = 77

def main():
    for name in ("pytest", "numpy"):
        if importlib.util.find_spec(name) is None:
            print(f"SKIP: {sys.executable} ({sys.version.split()[0]}) has no {name} "
                  "(Debian: apt-get install python3-pytest python3-numpy)")
            return SKIP
    module_dir = os.environ.get("REFLCAP_PYTHON_DIR", "")
    tag = f"cpython-{sys.version_info.major}{sys.version_info.minor}"
    if not glob.glob(os.path.join(module_dir, f"reflcap.{tag}*.so")):
        built = sorted(os.path.basename(p) for p in glob.glob(os.path.join(module_dir, "reflcap*.so")))
        print(f"SKIP: no reflcap module for {tag} in {module_dir!r} (found: {built or 'none'})")
        return SKIP
    import pytest
    return pytest.main(["-q", "-p", "no:cacheprovider", os.path.dirname(os.path.abspath(__file__))])

if __name__ == "__main__":
    sys.exit(main())
