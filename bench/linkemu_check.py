"""Measure every link profile through the emulator and print a Markdown table.

    python bench/linkemu_check.py [--profile 5g] [--mode userspace]

Same as ``python -m linkemu check`` run from ``bench/``.
"""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from linkemu.__main__ import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(["check", *sys.argv[1:]]))
