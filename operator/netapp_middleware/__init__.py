"""The robot-facing middleware: robots ask for a netapp by app name and get its URL; 5G-ERA robots work unmodified.

Layout: `app.py` builds the FastAPI app from `routers/`; `deployments.py` is the registry of robots' deployments;
`backends/` hold the `local` and `kubernetes` backends; `auth.py`, `catalogue.py` and `sources.py` the rest.
"""
