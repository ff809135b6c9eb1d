"""The malloc tunables that keep XLA's per-call buffers mapped (jaxsim.allocator)."""

import os
import subprocess
import sys

import pytest

from jaxsim import allocator

GLIBC = (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")


@pytest.mark.skipif(not GLIBC, reason="the tunables are glibc's")
def test_tunables_are_added_to_the_environment_once():
    environ = allocator.tuned_environment({"PATH": "/bin", "GLIBC_TUNABLES": "glibc.rtld.x=1"})
    assert environ["PATH"] == "/bin"
    assert environ["GLIBC_TUNABLES"] == ":".join(["glibc.rtld.x=1", *allocator.TUNABLES])
    assert allocator.tuned_environment(environ) is None          # already there: no restart
    own = {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=131072"}
    assert allocator.tuned_environment(own) is None              # the user's choice stands


@pytest.mark.skipif(not GLIBC, reason="the tunables are glibc's")
def test_restart_runs_the_same_command_with_the_tunables():
    script = ("import os, sys; from jaxsim import allocator; allocator.restart_with_tunables(); "
              "print(os.environ['GLIBC_TUNABLES']); print(sys.argv[1:])")
    environ = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    out = subprocess.run([sys.executable, "-c", script, "a", "b c"], env=environ, check=True,
                         capture_output=True, text=True).stdout.splitlines()
    assert out == [":".join(allocator.TUNABLES), "['a', 'b c']"]
