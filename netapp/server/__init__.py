"""The netapp server: FastAPI + python-socketio serving one shared Processor to many robots."""
