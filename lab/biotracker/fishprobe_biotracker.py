#!/usr/bin/env python3
"""Starts fishprobe as a BioTracker v4 observer component.

BioTracker v4's core launches only Python components: it runs
``python3 CMD`` with ``BIOTRACKER_COMPONENT_ADDRESS`` set, in its config file's folder.
This launcher replaces itself with ``fishprobe live biotracker`` (arguments after the script
name pass through, e.g. ``--log observer.log``), so the core talks to fishprobe directly.

Which fishprobe: ``$FISHPROBE_BIN`` if set, else ``fishprobe`` on the PATH, else
``~/.cargo/bin/fishprobe`` (where ``cargo install`` puts it). Standard library only; any
Python 3 that BioTracker's venv has will do.
"""

import os
import shutil
import sys


def find_fishprobe():
    """The fishprobe executable, or None."""
    explicit = os.environ.get("FISHPROBE_BIN")
    if explicit:
        return explicit if os.access(explicit, os.X_OK) else None
    on_path = shutil.which("fishprobe")
    if on_path:
        return on_path
    cargo = os.path.expanduser("~/.cargo/bin/fishprobe")
    return cargo if os.access(cargo, os.X_OK) else None


def main(argv):
    exe = find_fishprobe()
    if exe is None:
        # The core shows a component's stderr in its log; this is the only thing said there.
        sys.stderr.write(
            "fishprobe_biotracker: no fishprobe executable (set FISHPROBE_BIN, put fishprobe "
            "on the PATH, or install it with cargo install)\n"
        )
        return 2
    if not os.environ.get("BIOTRACKER_COMPONENT_ADDRESS") and "--address" not in argv:
        sys.stderr.write(
            "fishprobe_biotracker: BIOTRACKER_COMPONENT_ADDRESS is not set; BioTracker's core "
            "sets it when it starts a component (or pass --address 127.0.0.1:PORT)\n"
        )
        return 2
    os.execv(exe, [exe, "live", "biotracker"] + list(argv))
    return 1  # not reached: execv replaces this process


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
