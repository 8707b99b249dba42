"""Robot side of the middleware: ask for a netapp by app name, wait until it is Ready, get its URL.

Needs only `requests`; imports no server code::

    with MiddlewareClient("http://middleware:8080", "robot-1", secret) as mw:
        endpoint = mw.deploy("object-detection", placement="edge", on_progress=print)
        with mw.netapp_client(endpoint) as client:   # follows a failover's new URL by itself
            ...
    # leaving the block deletes the deployment

With `budget_ms`, `netapp_client` also reports the client's latency to the middleware every `report_every_s`, and
the middleware moves the robot to a better placement when it stays over budget (the client follows the move).
`deploy(app, hedge=["edge", "cloud"])` deploys on both placements at once; the endpoint's `urls` lists both.
`route(endpoint, [("cloud", time.time() + 30)])` says where the robot heads: the middleware readies the netapp there
before it arrives and moves it on time (the client moves make before break: `NetAppClient.move_to`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import quote

import requests

from netapp.client.errors import response_error
from netapp.client.stats import percentile
from netapp.client.tracing import SERVICE_NAME, RootSpan
from netapp.client.urls import http_url
from netapp.tracing import tracer_from_env

log = logging.getLogger(__name__)

Progress = Callable[[dict[str, Any]], None]


class MiddlewareError(RuntimeError):
    """The middleware refused a request (`status` is the HTTP status), or a deployment failed."""

    def __init__(self, message: str, status: int | None = None) -> None:
        super().__init__(message)
        self.status = status


class DeploymentFailed(MiddlewareError):
    def __init__(self, view: dict[str, Any]) -> None:
        super().__init__(f"deployment {view.get('id')} of {view.get('app')} failed: {view.get('message')}")
        self.view = view


@dataclass(frozen=True)
class Endpoint:
    """Where a deployed netapp answers."""

    deployment_id: str
    app: str
    url: str
    pool: str | None = None
    token: str | None = field(default=None, repr=False)  # the netapp's bearer token, when it needs one
    urls: tuple[str, ...] = ()  # a hedged deployment's netapps, primary first (else just `url`)
    tokens: tuple[str | None, ...] = field(default=(), repr=False)  # their bearer tokens, in the same order

    @classmethod
    def from_view(cls, view: dict[str, Any]) -> Endpoint:
        """The endpoint of a deployment's view (its current netapp, and a hedged one's every Ready netapp)."""
        ready = [h for h in view.get("hedge") or () if h.get("status") == "Ready" and h.get("url")]
        urls = tuple(h["url"] for h in ready) or (view["url"],)
        tokens = tuple(h.get("token") for h in ready) or (view.get("token"),)
        return cls(view["id"], view["app"], view["url"], view.get("pool"), view.get("token"), urls, tokens)


EARLY_REPORT_S = 0.25  # a window that crosses the budget is reported once it is this old (the middleware takes 0.2)
EARLY_CHECK_S = 0.05  # how often a window is looked at for that


def crossed(window_ms: list[float], budget_ms: float, last_over: bool) -> bool:
    """Whether a window so far crosses the budget after a report that was within it (pure): at least two results,
    their p95 over the budget. Reported at once, so that the middleware acts on a breach (a standby to move into, a
    netapp to start) without waiting for the end of the window."""
    return not last_over and len(window_ms) >= 2 and percentile(window_ms, 95) > budget_ms


def latency_report(latencies_ms: list[float], lost: int, deadline_ms: float, window_s: float) -> dict[str, Any]:
    """A report of one window (pure): its p95 (None without results) and frames that missed the deadline (late
    results, plus frames lost or dropped for it)."""
    late = sum(1 for latency in latencies_ms if latency > deadline_ms)
    return {
        "p95_ms": round(percentile(latencies_ms, 95), 1) if latencies_ms else None,
        "deadline_ms": deadline_ms,
        "missed": late + max(0, lost),
        "window_s": round(window_s, 3),
    }


class MiddlewareClient:
    """A robot's session with the middleware: logs in, deploys, follows and deletes its deployments."""

    def __init__(
        self,
        url: str,
        robot_id: str,
        secret: str,
        *,
        request_timeout: float = 10.0,
        long_poll_s: float = 30.0,
        tracer: Any = None,
    ) -> None:
        """`tracer`: a `netapp.tracing.Tracer` for the `deploy` span; None: as the OTel variables say (off unless
        configured, docs/tracing.md)."""
        self.url = http_url(url, "middleware")
        self.robot_id = robot_id
        self._secret = secret
        self._timeout = request_timeout
        self._long_poll_s = long_poll_s
        self._session = requests.Session()
        self._token: str | None = None
        self._token_expires = 0.0
        self._lock = threading.Lock()
        self._owned: list[str] = []
        self._followers: dict[str, list[tuple[threading.Thread, threading.Event]]] = {}
        self._tracer = tracer or tracer_from_env(SERVICE_NAME)

    # -- lifecycle -----------------------------------------------------------------------------------------------

    def __enter__(self) -> MiddlewareClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Delete the deployments this client made and stop following them."""
        for deployment_id in list(self._owned):
            try:
                self.delete(deployment_id)
            except (MiddlewareError, requests.RequestException) as exc:
                log.warning("could not delete deployment %s: %s", deployment_id, exc)
        for followers in self._followers.values():
            for _, stop in followers:
                stop.set()
        self._session.close()

    # -- API -----------------------------------------------------------------------------------------------------

    def apps(self) -> dict[str, Any]:
        return self._request("GET", "/apps").json()["apps"]

    def create(
        self,
        app: str,
        placement: str | None = None,
        reuse: bool = True,
        hedge: list[str] | None = None,
        trace: dict[str, str] | None = None,
        wait: float = 0.0,
    ) -> dict[str, Any]:
        """Ask for a deployment (on each placement of `hedge` at once); returns its first view, or with `wait` its
        view once Ready (or Failed), the middleware holding the answer up to `wait` seconds (an idle app woken).
        `trace`: the W3C trace context headers of the robot's span it belongs to."""
        body: dict[str, Any] = {"app": app, "reuse": reuse, **({"wait": wait} if wait > 0 else {})}
        if placement is not None:
            body["placement"] = placement
        if hedge:
            body["hedge"] = list(hedge)
        view = self._request("POST", "/deployments", json=body, headers=trace, timeout=self._timeout + wait).json()
        self._owned.append(view["id"])
        return view

    def status(self, deployment: Endpoint | str, wait: float = 0.0, since: int | None = None) -> dict[str, Any]:
        """The deployment's view; with `wait`, returns as soon as it changes from version `since`."""
        params: dict[str, Any] = {}
        if wait > 0:
            params["wait"] = wait
            if since is not None:
                params["since"] = since
        return self._request(
            "GET", f"/deployments/{_id(deployment)}", params=params, timeout=self._timeout + wait
        ).json()

    def deploy(
        self,
        app: str,
        placement: str | None = None,
        timeout: float = 300.0,
        reuse: bool = True,
        on_progress: Progress | None = None,
        hedge: list[str] | None = None,
    ) -> Endpoint:
        """Create a deployment and wait until it is Ready (a hedged one: on every placement that did not fail);
        raises DeploymentFailed or TimeoutError. Traced (docs/tracing.md): the robot's `deploy` span is the root
        of the middleware's trace of it."""
        span = RootSpan(self._tracer, "deploy", {"netapp.app": app}) if self._tracer is not None else None
        try:
            endpoint = self._deploy(app, placement, timeout, reuse, on_progress, hedge, span)
        except Exception as exc:
            if span is not None:
                span.end(type(exc).__name__)
            raise
        if span is not None:
            span.end()
        return endpoint

    def _deploy(
        self,
        app: str,
        placement: str | None,
        timeout: float,
        reuse: bool,
        on_progress: Progress | None,
        hedge: list[str] | None,
        span: RootSpan | None,
    ) -> Endpoint:
        trace = span.context.fields() if span is not None else None
        view = self.create(app, placement=placement, reuse=reuse, hedge=hedge, trace=trace)
        deadline = time.monotonic() + timeout
        while True:
            if on_progress is not None:
                on_progress(view)
            if view["status"] == "Ready" and view.get("url"):
                return Endpoint.from_view(view)
            if view["status"] == "Failed":
                raise DeploymentFailed(view)
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(
                    f"deployment {view['id']} of {app} not Ready after {timeout:.0f} s: "
                    f"{view['status']} {view.get('message', '')}"
                )
            view = self.status(view["id"], wait=min(remaining, self._long_poll_s), since=view["version"])

    def wake(self, deployment: Endpoint | str, wait: float = 30.0) -> Endpoint:
        """Come back to a deployment whose netapp may sleep (its app's `scaling.idleToZero`): the middleware wakes
        it and answers once it is Ready, holding the request up to `wait` seconds; raises DeploymentFailed or
        TimeoutError. Its endpoint (the same URL as before)."""
        path = f"/deployments/{_id(deployment)}/wake"
        view = self._request("POST", path, params={"wait": wait}, timeout=self._timeout + wait).json()
        if view["status"] == "Failed":
            raise DeploymentFailed(view)
        if view["status"] != "Ready" or not view.get("url"):
            raise TimeoutError(
                f"deployment {view['id']} not Ready after {wait:.0f} s: {view['status']} {view['message']}"
            )
        return Endpoint.from_view(view)

    def delete(self, deployment: Endpoint | str) -> None:
        deployment_id = _id(deployment)
        for _, stop in self._followers.pop(deployment_id, []):
            stop.set()
        try:
            self._request("DELETE", f"/deployments/{deployment_id}")
        except MiddlewareError as exc:
            if exc.status != 404:
                raise
        if deployment_id in self._owned:
            self._owned.remove(deployment_id)

    def follow(self, endpoint: Endpoint, on_change: Callable[[Endpoint], None]) -> threading.Event:
        """Call `on_change(new_endpoint)` from a background thread whenever the deployment is Ready at a new URL
        (a failover). Returns an Event that stops following when set; deleting the deployment stops it too."""
        stop = threading.Event()
        thread = threading.Thread(
            target=self._follow,
            args=(endpoint, on_change, stop),
            daemon=True,
            name=f"follow-{endpoint.deployment_id[:8]}",
        )
        self._followers.setdefault(endpoint.deployment_id, []).append((thread, stop))
        thread.start()
        return stop

    def report(
        self,
        deployment: Endpoint | str,
        p95_ms: float | None,
        deadline_ms: float,
        missed: int,
        window_s: float,
        url: str | None = None,
    ) -> dict[str, Any]:
        """Tell the middleware the latency measured on the deployment's netapp (at `url`); returns its decision
        (`reason`, `message`, `moveTo`). A report from a switchover's new URL lets the old netapp go."""
        body = {"p95_ms": p95_ms, "deadline_ms": deadline_ms, "missed": missed, "window_s": window_s, "url": url}
        return self._request("POST", f"/deployments/{_id(deployment)}/report", json=body).json()

    def route(self, deployment: Endpoint | str, waypoints: list[tuple[str, float]]) -> list[dict[str, Any]]:
        """Tell the middleware where the robot heads: (pool, eta) pairs, eta in Unix seconds (the next pool and when
        is a route of one; [] forgets the route). Returns the route it follows; MiddlewareError (422) names what is
        wrong with a route it refuses (an unknown pool, a time in the past, too many waypoints, flapping)."""
        body = {"route": [{"pool": pool, "eta": eta} for pool, eta in waypoints]}
        return self._request("PUT", f"/deployments/{_id(deployment)}/route", json=body).json()["route"]

    def rollouts(self, app: str) -> list[dict[str, Any]]:
        """The rollouts a change of `app`'s model started on its running netapps, one per NetApp: `phase`, `model`,
        `serving`, `reason`, `agreement` ... (`GET /apps/{app}/rollouts`, docs/rollouts.md)."""
        return self._request("GET", f"/apps/{quote(app, safe='')}/rollouts").json()["rollouts"]

    def standbys(self) -> dict[str, Any]:
        """The warm netapps waiting for robots and what they cost (`GET /standbys`)."""
        return self._request("GET", "/standbys").json()

    def netapp_client(
        self,
        endpoint: Endpoint,
        *,
        budget_ms: float | Callable[[], float] | None = None,
        report_every_s: float = 1.0,
        **kwargs: Any,
    ) -> Any:
        """A `NetAppClient` for the endpoint that switches to a failover's or a switchover's new URL by itself.

        With `budget_ms` (the latency the robot can accept, or a function that says it now: a control loop's pace
        may change; default the client's `deadline_ms`), its latency is reported every `report_every_s` so that
        the middleware can move the robot to a better placement when it stays over budget."""
        from netapp.client.netapp_client import NetAppClient  # numpy, OpenCV and Socket.IO: only when asked

        # A hedged endpoint's netapps all go to the client (give it a `policy`), unless their tokens differ: the
        # client sends one token to each, so it then serves the primary alone.
        urls = list(endpoint.urls) if len(set(endpoint.tokens)) <= 1 else [endpoint.url]
        if len(urls) < len(endpoint.urls):
            log.warning("the hedged netapps of %s need different tokens: serving the primary only", endpoint.app)
        client = NetAppClient(urls if len(urls) > 1 else endpoint.url, token=endpoint.token, **kwargs)
        if budget_ms is None:
            budget_ms = kwargs.get("deadline_ms")  # the robot's deadline is its budget

        def switch(new: Endpoint) -> None:
            client.token = new.token  # a switchover's NetApp has a token of its own
            client.move_to(new.url)  # make before break: the old netapp answers until the new one does

        stop = self.follow(endpoint, switch)
        if budget_ms is not None:
            reporter = threading.Thread(
                target=self._report_loop,
                args=(endpoint, client, budget_ms, report_every_s, stop),
                daemon=True,
                name=f"report-{endpoint.deployment_id[:8]}",
            )
            self._followers[endpoint.deployment_id].append((reporter, stop))
            reporter.start()
        return client

    # -- internals -------------------------------------------------------------------------------------------------

    def _report_loop(
        self,
        endpoint: Endpoint,
        client: Any,
        budget_ms: float | Callable[[], float],
        every_s: float,
        stop: threading.Event,
    ) -> None:
        """Report each window of the client's stats until `stop` (the deployment deleted, the client closed); a window
        that crosses the budget is reported early (`crossed`)."""
        stats = client.stats
        seen, lost_before = len(stats.latencies_ms), _lost(stats)
        started, last_over = time.monotonic(), False
        while not stop.wait(min(every_s, EARLY_CHECK_S)):
            now = time.monotonic()
            budget = budget_ms() if callable(budget_ms) else budget_ms
            with stats.lock:
                window = stats.latencies_ms[seen:]
            early = now - started >= EARLY_REPORT_S and crossed(window, budget, last_over)
            if now - started < every_s and not early:
                continue
            with stats.lock:
                window = stats.latencies_ms[seen:]
                seen, lost = len(stats.latencies_ms), _lost(stats)
            body = latency_report(window, lost - lost_before, budget, now - started)
            lost_before, started = lost, now
            last_over = body["p95_ms"] is not None and body["p95_ms"] > budget
            if body["p95_ms"] is None and body["missed"] == 0:
                continue  # not streaming: nothing to say
            try:
                decision = self.report(endpoint, **body, url=client.url)
            except MiddlewareError as exc:
                if exc.status == 404:
                    return  # deleted
                log.warning("reporting latency of %s: %s", endpoint.deployment_id, exc)
                continue
            except requests.RequestException as exc:
                log.warning("reporting latency of %s: %s", endpoint.deployment_id, exc)
                continue
            if decision.get("moveTo"):
                log.info("the middleware moves deployment %s: %s", endpoint.deployment_id, decision["message"])

    def _follow(self, endpoint: Endpoint, on_change: Callable[[Endpoint], None], stop: threading.Event) -> None:
        url, since = endpoint.url, None
        while not stop.is_set():
            try:
                # The first look does not wait: the URL may have changed since `endpoint` was made.
                view = self.status(
                    endpoint.deployment_id, wait=self._long_poll_s if since is not None else 0.0, since=since
                )
            except MiddlewareError as exc:
                if exc.status == 404:
                    return  # deleted
                log.warning("following %s: %s", endpoint.deployment_id, exc)
                stop.wait(1.0)
                continue
            except requests.RequestException as exc:  # middleware restarting: keep trying
                log.warning("following %s: %s", endpoint.deployment_id, exc)
                stop.wait(1.0)
                continue
            since = view["version"]
            if not stop.is_set() and view["status"] == "Ready" and view.get("url") and view["url"] != url:
                url = view["url"]
                log.info("deployment %s moved to %s (%s)", endpoint.deployment_id, url, view.get("pool"))
                try:
                    on_change(Endpoint.from_view(view))
                except Exception:  # the callback's failure must not stop following
                    log.exception("switching to %s failed", url)

    def _auth_header(self) -> dict[str, str]:
        with self._lock:
            # Refresh a minute before expiry; log in again when there is no token (or it was refused).
            if self._token is not None and time.time() > self._token_expires - 60:
                response = self._session.post(
                    f"{self.url}/auth/refresh",
                    timeout=self._timeout,
                    headers={"Authorization": f"Bearer {self._token}"},
                )
                self._token = None
                if response.ok:
                    self._store_token(response.json())
            if self._token is None:
                response = self._session.post(
                    f"{self.url}/auth/token",
                    timeout=self._timeout,
                    json={"robot_id": self.robot_id, "secret": self._secret},
                )
                if not response.ok:
                    raise MiddlewareError(
                        f"login as {self.robot_id} failed: {response.status_code} {response_error(response)}",
                        response.status_code,
                    )
                self._store_token(response.json())
            return {"Authorization": f"Bearer {self._token}"}

    def _store_token(self, body: dict[str, Any]) -> None:
        self._token = body["access_token"]
        self._token_expires = float(body["expires_at"])

    def _request(
        self,
        method: str,
        path: str,
        timeout: float | None = None,
        headers: dict[str, str] | None = None,
        **kwargs: Any,
    ) -> requests.Response:
        for attempt in (1, 2):
            response = self._session.request(
                method,
                f"{self.url}{path}",
                headers={**self._auth_header(), **(headers or {})},
                timeout=timeout or self._timeout,
                **kwargs,
            )
            if response.status_code == 401 and attempt == 1:
                with self._lock:
                    self._token = None  # e.g. the middleware restarted with a new key: log in again
                continue
            if not response.ok:
                raise MiddlewareError(
                    f"{method} {path}: {response.status_code} {response_error(response)}", response.status_code
                )
            return response
        raise AssertionError("unreachable")


def _lost(stats: Any) -> int:
    """Frames that got no result in time: lost, and dropped by a netapp for the deadline (where counted)."""
    return int(stats.lost) + int(getattr(stats, "deadline_dropped", 0))


def _id(deployment: Endpoint | str) -> str:
    return deployment.deployment_id if isinstance(deployment, Endpoint) else deployment
