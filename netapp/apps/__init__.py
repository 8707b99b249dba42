"""The command-line applications (`netapp stream`, `watch`, `rollout`, `ros2`, `model`, `profile`): the top layer.

Each app is a module defining `add_arguments(parser)` (argparse only, so that `netapp --help` and `netapp serve`
stay light) and `run(args) -> int`, which imports the libraries below it (netapp.client, netapp.ros,
netapp.models) when it runs. Nothing imports this package but the entry point, netapp/cli.py.
"""
