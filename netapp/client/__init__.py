"""The robot side: a client for netapps and for the middleware. Imports no server code.

from netapp.client import NetAppClient

with NetAppClient("http://edge:5896", transport="ws") as client:
    client.send(frame)              # numpy BGR array or JPEG bytes; never blocks, newest frame wins
    for result in client.results(timeout=1.0):
        print(result.latency_ms, result.detections)
"""

from netapp.client.errors import NetAppError, NetAppRefused
from netapp.client.netapp_client import NetAppClient, Result, Switch
from netapp.client.send_settings import SendSettings

__all__ = ["NetAppClient", "NetAppError", "NetAppRefused", "Result", "SendSettings", "Switch", "MiddlewareClient"]


def __getattr__(name: str):
    if name == "MiddlewareClient":  # the middleware client needs only `requests`: imported when asked for
        from netapp.client.middleware import MiddlewareClient

        return MiddlewareClient
    raise AttributeError(name)
