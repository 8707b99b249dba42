"""The robot-facing middleware: robots ask for a netapp by app name and get its URL; 5G-ERA robots work unmodified.

Layout: `app.py` builds the FastAPI app from `routers/` over the shared `services.py`; `deployments.py` is the
registry of robots' deployments; `backends/` hold the `local` and `kubernetes` backends; `action_plan.py` shows a
deployment as a 5G-ERA action plan; `auth.py`, `catalogue.py` and `sources.py` the rest.
"""
