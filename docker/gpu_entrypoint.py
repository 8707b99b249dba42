"""The GPU image's entrypoint: load the NVIDIA libraries from the wheels, say which, then run the `netapp` command.

    python entrypoint.py serve --model /models/model.onnx ...

The libraries must be in the process before onnxruntime creates a session (netapp.models.gpu_libs); a separate
process could not load them for the server, so this runs the command line in-process.
"""

from __future__ import annotations

import sys

from netapp.cli import main
from netapp.models.gpu_libs import preload

if __name__ == "__main__":
    print(preload().describe(), file=sys.stderr, flush=True)
    sys.exit(main(sys.argv[1:]))
