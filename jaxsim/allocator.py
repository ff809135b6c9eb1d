"""Keep freed memory inside the process, so that XLA's per-call buffers stop faulting pages in.

XLA on CPU allocates the temporary buffers of every call with malloc and frees them when the call
returns. glibc hands blocks above its mmap threshold straight back to the kernel (and trims the
heap above its trim threshold), so each call of a batch-4096 step maps tens of MB of fresh pages
again: about 10,000 page faults per MABA solve of 4096 humanoids, ~20% of its time
(docs/benchmarks.md, "Where the step's time goes"). Raising both thresholds keeps that memory for
reuse; the process's resident size then stays at its peak, which a simulation run reaches early.

glibc reads these tunables only when a process starts, and `mallopt` refuses an mmap threshold
above 32 MiB (XLA's temporary buffer is larger), so they must be in the environment before Python
starts. `restart_with_tunables` re-executes the current command with them set (once: the restarted
process finds them set); the `takeoff` command and the benchmarks call it first. In your own scripts, start Python with

    GLIBC_TUNABLES=glibc.malloc.mmap_threshold=536870912:glibc.malloc.trim_threshold=536870912

A GLIBC_TUNABLES that already sets the mmap threshold is left alone (set it to glibc's default,
131072, to opt out). Other platforms and C libraries are left alone too.
"""

import os
import sys

TUNABLES = ("glibc.malloc.mmap_threshold=536870912",
            "glibc.malloc.trim_threshold=536870912")


def tuned_environment(environ):
    """The environment with the tunables added, or None when there is nothing to change (not
    glibc, or GLIBC_TUNABLES already chooses an mmap threshold). A trim threshold the user set is
    kept."""
    try:
        libc = os.confstr("CS_GNU_LIBC_VERSION") or ""
    except (AttributeError, ValueError, OSError):
        libc = ""
    current = environ.get("GLIBC_TUNABLES", "")
    if not libc.startswith("glibc") or "glibc.malloc.mmap_threshold" in current:
        return None
    added = [t for t in TUNABLES if t.split("=")[0] not in current]
    return {**environ, "GLIBC_TUNABLES": ":".join(filter(None, [current, *added]))}


def restart_with_tunables():
    """Re-execute this process's command with the tunables in its environment (see the module
    docstring). Returns without doing anything when they are set already, do not apply, or the
    command cannot be run again (a script read from standard input)."""
    environ = tuned_environment(os.environ)
    if environ is None or len(sys.orig_argv) < 2 or sys.argv[0] in ("", "-"):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, sys.orig_argv, environ)
