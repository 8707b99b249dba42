"""netapp-toolkit: offload robot perception to edge or cloud network applications.

The package root imports nothing heavy: `netapp.client` must work on a robot that has neither onnxruntime nor
FastAPI installed.
"""

__version__ = "0.1.0"
