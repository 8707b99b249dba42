"""Operator benchmark against the kmock-based API emulator.

The operator runs as its own process (`netapp operator`, as in a cluster) so that its RSS is its own; the emulator
runs here. Measures the time from a NetApp's creation to its status.url (one at a time, p50/p95), the time to
reconcile a burst of NetApps (all created at once, until every one has a url), and the operator's RSS.

    python -m bench.operator_bench [--latency-samples 100] [--burst 500]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import gc
import os
import statistics
import sys
import tempfile
import time
from typing import Any

import aiohttp
import kmock
import psutil
from netapp_operator.constants import API_VERSION, LABEL_POOL, NETAPP_IMAGE, NETAPP_PLURAL
from netapp_operator.kube import Kube, environment_login

from netapp.serve_process import free_port

# The emulator is test scaffolding (tests/support/), not part of the package: import it from the repository root.
from tests.support.kube_emulator import Emulator, declare, kubeconfig

NETAPPS = f"{API_VERSION}/{NETAPP_PLURAL}"
NETAPP_RESOURCE = kmock.resource(NETAPPS)


def url_of(em: Emulator, namespace: str, name: str) -> str | None:
    # By key (the emulator's own lookup): kmock's `objects[...]` scans every object, thousands per poll.
    obj = em.lookup(NETAPP_RESOURCE, namespace, name)
    return None if obj is None else (obj.raw.get("status") or {}).get("url")


async def wait_urls(em: Emulator, namespace: str, names: list[str], timeout: float) -> float:
    """Poll the emulator's memory (no HTTP) until every NetApp has a url; returns the completion time.

    After a first look at every name, a poll looks again only at the NetApps that requests served since the last
    poll named (the emulator logs each request once it is served): a url comes with a request, the operator's
    status write. Scanning every pending name each poll cost O(NetApps) per poll, a tenth of the bench process's CPU
    in a burst of 4,000 (py-spy), taken from the operator on the same cores."""
    served = len(em.log)
    pending = {n for n in names if url_of(em, namespace, n) is None}
    deadline = time.perf_counter() + timeout
    while pending:
        if time.perf_counter() > deadline:
            raise TimeoutError(f"{len(pending)} NetApps still have no url after {timeout}s")
        await asyncio.sleep(0.001 if len(pending) < 10 else 0.05)
        new, served = em.log[served:], len(em.log)
        named = {r.name for r in new if r.namespace == namespace and r.resource == NETAPP_RESOURCE} & pending
        pending -= {n for n in named if url_of(em, namespace, n) is not None}
    return time.perf_counter()


def request_counts(log: list[Any]) -> collections.Counter[str]:
    """The requests the emulator served, by verb and resource (e.g. "update netapps/status"): the bench's own
    creates are among them (one "create netapps" per NetApp)."""
    counts: collections.Counter[str] = collections.Counter()
    for request in log:
        if request.resource is None:
            continue
        what = request.resource.plural + (f"/{request.subresource}" if request.subresource else "")
        counts[f"{request.action.value if request.action else request.method} {what}"] += 1
    return counts


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


async def main(args: argparse.Namespace) -> int:
    async with Emulator() as em, kmock.Server(em) as server:
        declare(em)
        base = str(server.url).rstrip("/")
        with tempfile.NamedTemporaryFile("w", suffix=".kubeconfig", delete=False) as f:
            f.write(kubeconfig(base))
        # The benchmark's own client is the operator's: it logs in through the same kubeconfig.
        kube = Kube(lambda: environment_login(f.name), manager="netapp-operator-bench")
        async with aiohttp.ClientSession() as http:
            for pool in ("edge", "cloud"):
                await kube.create(
                    {
                        "apiVersion": "v1",
                        "kind": "Node",
                        "metadata": {"name": f"{pool}-1", "labels": {LABEL_POOL: pool}},
                        "status": {
                            "conditions": [{"type": "Ready", "status": "True"}],
                            "addresses": [{"type": "InternalIP", "address": "10.0.0.1"}],
                        },
                    },
                )
                await kube.create(
                    {
                        "apiVersion": API_VERSION,
                        "kind": "NodePool",
                        "metadata": {"name": pool},
                        "spec": {
                            "type": pool,
                            "nodeSelector": {LABEL_POOL: pool},
                            "priority": 10 if pool == "edge" else 0,
                            "access": {"serviceType": "NodePort"},
                        },
                    },
                )

            port = free_port()
            proc = await asyncio.create_subprocess_exec(
                # ERROR: kopf warns about every handler it cancels at SIGTERM, which is expected here.
                sys.executable,
                "-m",
                "netapp",
                "--log-level",
                "ERROR",
                "operator",
                "--all-namespaces",
                f"--liveness=http://127.0.0.1:{port}/healthz",
                env={**os.environ, "KUBECONFIG": f.name},
            )
            ps = psutil.Process(proc.pid)
            peak = 0
            try:
                deadline = time.monotonic() + 60
                while True:  # wait for the operator's liveness endpoint
                    try:
                        async with http.get(f"http://127.0.0.1:{port}/healthz") as r:
                            if r.status == 200:
                                break
                    except aiohttp.ClientError:
                        pass
                    if time.monotonic() > deadline or proc.returncode is not None:
                        raise RuntimeError("the operator did not start")
                    await asyncio.sleep(0.05)
                rss_idle = ps.memory_info().rss

                def body(ns: str, name: str) -> dict[str, Any]:
                    return {
                        "apiVersion": API_VERSION,
                        "kind": "NetApp",
                        "metadata": {"name": name, "namespace": ns},
                        "spec": {"image": NETAPP_IMAGE},
                    }

                latencies = []
                for i in range(args.warmup + args.latency_samples):
                    name = f"lat-{i}"
                    t0 = time.perf_counter()
                    await kube.create(body("lat", name))
                    done = await wait_urls(em, "lat", [name], timeout=60)
                    if i >= args.warmup:
                        latencies.append((done - t0) * 1000)
                    peak = max(peak, ps.memory_info().rss)

                names = [f"burst-{i}" for i in range(args.burst)]
                t0 = time.perf_counter()
                cpu0 = (sum(ps.cpu_times()[:2]), sum(psutil.Process().cpu_times()[:2]))
                sem = asyncio.Semaphore(32)

                async def create(name: str) -> None:
                    async with sem:
                        await kube.create(body("burst", name))

                sampler_stop = asyncio.Event()

                async def sample() -> None:
                    nonlocal peak
                    while not sampler_stop.is_set():
                        peak = max(peak, ps.memory_info().rss)
                        # The emulator keeps every version of every object and every request it served: out of
                        # this process's cyclic collector as they accumulate, whose full passes walked them all
                        # again and again (gc.callbacks: 40 % of this process's CPU in a burst of 3,000). A real
                        # API server is not a Python process on the operator's cores; the young objects are still
                        # collected as before.
                        gc.freeze()
                        await asyncio.sleep(0.2)

                sampler = asyncio.create_task(sample())
                logged = len(em.log)
                await asyncio.gather(*(create(n) for n in names))
                created = time.perf_counter()
                done = await wait_urls(em, "burst", names, timeout=600)
                sampler_stop.set()
                await sampler
                rss_end = ps.memory_info().rss
                cpu = (sum(ps.cpu_times()[:2]) - cpu0[0], sum(psutil.Process().cpu_times()[:2]) - cpu0[1])
                peak = max(peak, rss_end)
                requests = request_counts(em.log[logged:])
            finally:
                proc.terminate()
                try:
                    await asyncio.wait_for(proc.wait(), timeout=20)
                except asyncio.TimeoutError:
                    proc.kill()
                await kube.close()
                os.unlink(f.name)

    mb = 1024 * 1024
    rows = [
        ("create -> status.url, p50", f"{statistics.median(latencies):.1f} ms", "<= 10 ms"),
        ("create -> status.url, p95", f"{percentile(latencies, 0.95):.1f} ms", ""),
        ("create -> status.url, max", f"{max(latencies):.1f} ms", ""),
        (f"{args.burst} NetApps: all created", f"{created - t0:.1f} s", ""),
        (f"{args.burst} NetApps: all with status.url", f"{done - t0:.1f} s", "< 60 s"),
        # Which side is the bottleneck: a side near (wall time x 1 core) is saturated.
        (f"{args.burst} NetApps: operator CPU", f"{cpu[0]:.1f} s", ""),
        (f"{args.burst} NetApps: emulator CPU", f"{cpu[1]:.1f} s", ""),
        (
            f"{args.burst} NetApps: API requests per NetApp",
            f"{sum(requests.values()) / max(1, args.burst):.1f}",
            "(the bench's create included)",
        ),
        ("operator RSS, idle", f"{rss_idle / mb:.0f} MB", ""),
        ("operator RSS, peak", f"{peak / mb:.0f} MB", "< 300 MB at 10,000"),
        (
            f"operator RSS, after {args.burst + args.latency_samples + args.warmup} NetApps",
            f"{rss_end / mb:.0f} MB",
            "",
        ),
    ]
    width = max(len(r[0]) for r in rows)
    print(f"{'metric':<{width}}  {'value':>10}  goal")
    print(f"{'-' * width}  {'-' * 10}  --------")
    for metric, value, goal in rows:
        print(f"{metric:<{width}}  {value:>10}  {goal}")
    print(
        "API requests during the burst, per NetApp: "
        + ", ".join(f"{what} {n / max(1, args.burst):.2f}" for what, n in requests.most_common())
    )
    print(
        f"(latency over {len(latencies)} NetApps created one at a time, after {args.warmup} warm-up; "
        f"python {sys.version.split()[0]}, {psutil.cpu_count()} CPUs, emulator and operator on the same machine)"
    )
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latency-samples", type=int, default=100)
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--burst", type=int, default=500)
    sys.exit(asyncio.run(main(parser.parse_args())))
