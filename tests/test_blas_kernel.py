"""One BLAS kernel set on every machine (daq.pin_blas_kernel): OpenBLAS picks kernels by CPU and they round
differently, and the same proposal came out differently on two machines until both used the same set. One BLAS
thread (daq.pin_blas_threads): OpenBLAS splits work by its thread count, one a core, and a split rounds otherwise."""

from __future__ import annotations

import os
import subprocess
import sys

import daq

# what numpy's and scipy's OpenBLAS loaded in a fresh interpreter, with or without importing daq first: their kernel
# sets, their thread counts, and OPENBLAS_NUM_THREADS there
OPENBLAS = """
import ctypes, glob, os, sys
if sys.argv[1] == 'daq':
    import daq
import numpy, scipy.linalg
def call(package, lib, symbol, restype=ctypes.c_int):
    path = glob.glob(os.path.join(os.path.dirname(package.__file__) + '.libs', lib))[0]
    fn = getattr(ctypes.CDLL(path), symbol)
    fn.restype = restype
    out = fn()
    return out.decode() if isinstance(out, bytes) else out
print(call(numpy, 'libscipy_openblas64_*.so', 'scipy_openblas_get_corename64_', ctypes.c_char_p),
      call(scipy, 'libscipy_openblas-*.so', 'scipy_openblas_get_corename', ctypes.c_char_p),
      call(numpy, 'libscipy_openblas64_*.so', 'scipy_openblas_get_num_threads64_'),
      call(scipy, 'libscipy_openblas-*.so', 'scipy_openblas_get_num_threads'), os.environ.get('OPENBLAS_NUM_THREADS'))
"""


def users_shell(**env: str) -> dict[str, str]:
    """This environment without what daq sets (the suite's own process imported daq), as a user's shell has it."""
    return {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", *daq.BLAS_THREAD_VARIABLES)} | env


def openblas(first: str, **env: str) -> list[str]:
    r = subprocess.run([sys.executable, "-c", OPENBLAS, first], capture_output=True, text=True, env=users_shell(**env))
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


def corenames(first: str, **env: str) -> list[str]:
    return openblas(first, **env)[:2]


def blas_threads(first: str, **env: str) -> list[str]:
    """numpy's and scipy's OpenBLAS thread counts, and OPENBLAS_NUM_THREADS."""
    return openblas(first, **env)[2:]


def test_numpy_and_scipy_compute_with_the_pinned_kernels_wherever_the_cpu_runs_them():
    pinned = {"avx2", "fma"} <= daq.cpu_flags()  # x86's flags (another architecture's cpuinfo has no such line)
    own = corenames("numpy")  # OpenBLAS's own choice for this CPU
    with_daq = corenames("daq")
    assert with_daq == ([daq.BLAS_KERNEL] * 2 if pinned else own), (own, with_daq)
    # a kernel set the environment names is the user's choice, not overridden
    assert corenames("daq", OPENBLAS_CORETYPE="Sandybridge") == ["Sandybridge"] * 2


def test_the_rule_reads_the_cpu_flags_and_leaves_the_rest_to_openblas(tmp_path):
    """Run in a fresh interpreter that has not loaded numpy (OpenBLAS reads the variable as it loads)."""
    cases = {"avx2 fma": daq.BLAS_KERNEL, "sse4_2 avx": None, "avx2": None, "": None}
    assert daq.cpu_flags(str(tmp_path / "none")) == set()  # no cpuinfo (another system): nothing pinned
    for flags, expect in cases.items():
        info = tmp_path / f"cpuinfo-{flags.replace(' ', '-')}"
        info.write_text(f"processor\t: 0\nvendor_id\t: x\nflags\t\t: fpu {flags} sse2\n\nprocessor\t: 1\n" if flags
                        else "processor\t: 0\nFeatures\t: fp asimd evtstrm\n")  # "": an aarch64 cpuinfo, no flags
        code = (f"import os, sys; os.environ.pop('OPENBLAS_CORETYPE', None); import daq; "
                f"os.environ.pop('OPENBLAS_CORETYPE', None); r = daq.pin_blas_kernel({str(info)!r}); "
                f"print(r, os.environ.get('OPENBLAS_CORETYPE'), 'numpy' in sys.modules)")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.split()
        assert out == [str(expect), str(expect), "False"], (flags, out)
    # numpy loaded already: too late to choose, said as None, the environment untouched
    code = ("import os, sys; import numpy; os.environ.pop('OPENBLAS_CORETYPE', None); import daq; "
            "print(daq.pin_blas_kernel(), 'OPENBLAS_CORETYPE' in os.environ)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.split() == ["None",
                                                                                                         "False"]


def test_numpy_and_scipy_compute_on_one_blas_thread_unless_the_user_names_a_count():
    assert blas_threads("daq") == ["1", "1", daq.BLAS_THREADS]  # and our processes' children inherit it
    assert blas_threads("daq", OPENBLAS_NUM_THREADS="2") == ["2", "2", "2"]  # the user's count, kept
    assert blas_threads("daq", OMP_NUM_THREADS="2") == ["2", "2", "None"]  # OpenBLAS reads this one too
    # numpy loaded first: OpenBLAS has chosen (a thread a core), said as None and the environment left alone
    assert blas_threads("numpy")[2] == "None"
    code = "import numpy, daq; print(daq.pin_blas_threads())"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=users_shell()).stdout.split() == ["None"]
