#!/usr/bin/env python3
"""The Grafana dashboards of the chart, from code: `python -m tools.dashboards` writes charts/netapp-toolkit/files/
dashboards/*.json (committed; a test regenerates them and compares the bytes), `--check` only compares.

Four dashboards: the fleet of netapps, one netapp, one robot, and the control plane (operator and middleware). Each
panel is a row of DASHBOARDS: a title, a unit and its PromQL queries; grafana-foundation-sdk (Grafana Labs' own
builders, generated from Grafana's schemas) turns them into dashboard JSON. The queries read the recording rules of
charts/netapp-toolkit/files/rules.yaml (`netapp:...`) and the metrics of the netapp, operator and middleware.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
from dataclasses import dataclass, field

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "charts" / "netapp-toolkit" / "files" / "dashboards"

NETAPP = 'namespace=~"$namespace", netapp=~"$netapp"'
RATE = "[$__rate_interval]"


@dataclass(frozen=True)
class Query:
    expr: str
    legend: str


@dataclass(frozen=True)
class PanelSpec:
    title: str
    unit: str
    queries: tuple[Query, ...]
    description: str = ""


@dataclass(frozen=True)
class Variable:
    name: str
    label: str
    query: str  # label_values(...)


@dataclass(frozen=True)
class DashboardSpec:
    uid: str
    title: str
    description: str
    variables: tuple[Variable, ...]
    panels: tuple[PanelSpec, ...] = field(default_factory=tuple)


def _q(expr: str, legend: str) -> Query:
    return Query(expr, legend)


NAMESPACE = Variable("namespace", "Namespace", "label_values(netapp_robots_per_replica, namespace)")
NETAPP_VAR = Variable("netapp", "NetApp", 'label_values(netapp_robots_per_replica{namespace=~"$namespace"}, netapp)')
ROBOT = Variable("robot", "Robot", "label_values(netapp_middleware_robot_budget_seconds, robot)")


def _quantile(q: float, metric: str, by: str) -> str:
    return f"histogram_quantile({q}, sum by (le{by}) (rate({metric}_bucket{{{NETAPP}}}{RATE})))"


DASHBOARDS: tuple[DashboardSpec, ...] = (
    DashboardSpec(
        "netapp-fleet",
        "NetApp / Fleet",
        "Every netapp: latency, results, robots and load, frames dropped and refused.",
        (NAMESPACE,),
        (
            PanelSpec(
                "p95 latency, receive to result",
                "s",
                (_q('netapp:netapp_latency_seconds:p95{namespace=~"$namespace"}', "{{namespace}}/{{netapp}}"),),
                "NetAppLatencyHigh fires over monitoring.rules.latencyP95Seconds.",
            ),
            PanelSpec(
                "Results per second",
                "reqps",
                (_q('netapp:netapp_frames_processed:rate{namespace=~"$namespace"}', "{{namespace}}/{{netapp}}"),),
            ),
            PanelSpec(
                "Robots",
                "short",
                (_q('netapp:netapp_robots:sum{namespace=~"$namespace"}', "{{namespace}}/{{netapp}}"),),
            ),
            PanelSpec(
                "Load: robots over the replicas' optimal limit",
                "percentunit",
                (_q('netapp:netapp_load_ratio:avg{namespace=~"$namespace"}', "{{namespace}}/{{netapp}}"),),
                "Over 100 %: NetAppReplicasSaturated.",
            ),
            PanelSpec(
                "Frames dropped for their deadline",
                "percentunit",
                (
                    _q(
                        'netapp:netapp_frames_deadline_dropped:rate{namespace=~"$namespace"}'
                        ' / netapp:netapp_frames_received:rate{namespace=~"$namespace"}',
                        "{{namespace}}/{{netapp}}",
                    ),
                ),
                "NetAppDeadlineMisses fires over monitoring.rules.deadlineMissRatio.",
            ),
            PanelSpec(
                "Frames refused, robots turned away",
                "reqps",
                (
                    _q(
                        'netapp:netapp_frames_rejected:rate{namespace=~"$namespace"}', "{{namespace}}/{{netapp}} frames"
                    ),
                    _q(
                        'netapp:netapp_sessions_refused:rate{namespace=~"$namespace"}',
                        "{{namespace}}/{{netapp}} robots",
                    ),
                ),
                "NetAppFramesRefused.",
            ),
        ),
    ),
    DashboardSpec(
        "netapp-netapp",
        "NetApp / One netapp",
        "One netapp's replicas: latency by transport, inference, the fate of frames, queue, capacity.",
        (NAMESPACE, NETAPP_VAR),
        (
            PanelSpec(
                "Latency, receive to result, by transport",
                "s",
                tuple(
                    _q(_quantile(q, "netapp_latency_seconds", ", transport"), f"p{int(q * 100)} {{{{transport}}}}")
                    for q in (0.5, 0.95, 0.99)
                ),
            ),
            PanelSpec(
                "Inference time per batch",
                "s",
                (
                    _q(_quantile(0.5, "netapp_inference_seconds", ""), "p50"),
                    _q(_quantile(0.95, "netapp_inference_seconds", ""), "p95"),
                ),
            ),
            PanelSpec(
                "Frames per second, by fate",
                "reqps",
                tuple(
                    _q(f"sum (rate(netapp_frames_{fate}_total{{{NETAPP}}}{RATE}))", fate)
                    for fate in ("received", "processed", "dropped", "deadline_dropped")
                ),
                "dropped: superseded by a newer frame of its robot; deadline_dropped: could not meet its deadline.",
            ),
            PanelSpec(
                "Refused",
                "reqps",
                (
                    _q(f"sum by (reason) (rate(netapp_frames_rejected_total{{{NETAPP}}}{RATE}))", "frames: {{reason}}"),
                    _q(f"sum (rate(netapp_sessions_refused_total{{{NETAPP}}}{RATE}))", "robots turned away"),
                ),
            ),
            PanelSpec(
                "Queue depth",
                "short",
                (_q(f"netapp_queue_depth{{{NETAPP}}}", "{{pod}}"),),
            ),
            PanelSpec(
                "Robots and capacity per replica",
                "short",
                (
                    _q(f"netapp_robots_per_replica{{{NETAPP}}}", "{{pod}} robots"),
                    _q(f"netapp_capacity_robots{{{NETAPP}}}", "{{pod}} {{kind}} limit"),
                ),
            ),
            PanelSpec(
                "Results per second: capacity and the median robot's demand",
                "reqps",
                (
                    _q(f"netapp_capacity_results_per_second{{{NETAPP}}}", "{{pod}} capacity"),
                    _q(f"netapp_robot_input_fps{{{NETAPP}}}", "{{pod}} median robot"),
                ),
            ),
            PanelSpec(
                "Frames per batch",
                "short",
                (
                    _q(
                        f"sum (rate(netapp_batch_size_sum{{{NETAPP}}}{RATE}))"
                        f" / sum (rate(netapp_batch_size_count{{{NETAPP}}}{RATE}))",
                        "mean",
                    ),
                ),
            ),
            PanelSpec(
                "Sessions by transport",
                "short",
                (_q(f"sum by (transport) (netapp_active_sessions{{{NETAPP}}})", "{{transport}}"),),
            ),
            PanelSpec(  # docs/rollouts.md: a candidate model on its shadow (NaN, no line, when none runs)
                "Model rollout: agreement and speed",
                "short",
                (
                    _q(f"netapp_rollout_agreement{{{NETAPP}}}", "{{pod}} agreement (F1)"),
                    _q(
                        f'netapp_rollout_p95_seconds{{{NETAPP}, model="candidate"}}'
                        f' / ignoring (model) netapp_rollout_p95_seconds{{{NETAPP}, model="current"}}',
                        "{{pod}} p95 candidate / current",
                    ),
                ),
            ),
        ),
    ),
    DashboardSpec(
        "netapp-robot",
        "NetApp / One robot",
        "What a robot reports to the middleware (MiddlewareClient with budget_ms), beside its netapp's own share.",
        (ROBOT,),
        (
            PanelSpec(
                "p95 latency against the budget, as the robot measures it",
                "s",
                (
                    _q(
                        'netapp_middleware_robot_latency_p95_seconds{robot=~"$robot"}', "{{robot}} p95 on {{placement}}"
                    ),
                    _q('netapp_middleware_robot_budget_seconds{robot=~"$robot"}', "{{robot}} budget"),
                ),
                "NetAppRobotLatencyOverBudget fires while p95 stays over the budget.",
            ),
            PanelSpec(
                "Its netapp's p95, receive to result",
                "s",
                (
                    _q(
                        'max by (netapp, robot) (0 * netapp_middleware_robot_budget_seconds{robot=~"$robot"})'
                        " + on (netapp) group_left () netapp:netapp_latency_seconds:p95",
                        "{{robot}} on {{netapp}}",
                    ),
                ),
                "The netapp's share of the robot's latency; the rest is the link and the robot.",
            ),
            PanelSpec(
                "Frames that missed their deadline",
                "reqps",
                (_q('netapp_middleware_robot_missed_per_second{robot=~"$robot"}', "{{robot}}"),),
            ),
        ),
    ),
    DashboardSpec(
        "netapp-control-plane",
        "NetApp / Control plane",
        "The operator (NetApps, node pools, reconciles) and the middleware (robots' deployments).",
        (),
        (
            PanelSpec(
                "NetApps by phase",
                "short",
                (_q("sum by (phase) (netapp_operator_netapp_phase)", "{{phase}}"),),
            ),
            PanelSpec(
                "NetApps Ready",
                "short",
                (
                    _q("sum (netapp_operator_netapp_ready)", "Ready"),
                    _q("count (netapp_operator_netapp_ready)", "all"),
                ),
                "NetAppNotReady fires for a NetApp not Ready for monitoring.rules.for.notReady.",
            ),
            PanelSpec(
                "Node pools: ready nodes",
                "short",
                (
                    _q("netapp_operator_nodepool_ready_nodes", "{{pool}} ready"),
                    _q("netapp_operator_nodepool_nodes", "{{pool}} all"),
                ),
                "NetAppNodePoolNoReadyNodes fires at 0 ready.",
            ),
            PanelSpec(
                "Reconciles per second",
                "reqps",
                (_q(f"sum by (result) (rate(netapp_operator_reconciles_total{RATE}))", "{{result}}"),),
                "NetAppOperatorReconcileErrors fires while errors go on.",
            ),
            PanelSpec("Reconcile queue", "short", (_q("sum (netapp_operator_queue_depth)", "waiting"),)),
            PanelSpec(
                "Robots' deployments",
                "short",
                (_q("sum by (app, placement) (netapp_middleware_deployments)", "{{app}} on {{placement}}"),),
            ),
        ),
    ),
)


def build(spec: DashboardSpec) -> dict:
    """One dashboard's JSON model, built with grafana-foundation-sdk."""
    from grafana_foundation_sdk.builders import common, dashboard, prometheus, timeseries
    from grafana_foundation_sdk.cog.encoder import JSONEncoder
    from grafana_foundation_sdk.models.common import LegendDisplayMode, LegendPlacement, SortOrder, TooltipDisplayMode
    from grafana_foundation_sdk.models.dashboard import DataSourceRef, VariableRefresh

    source = DataSourceRef(type_val="prometheus", uid="${datasource}")
    board = (
        dashboard.Dashboard(spec.title)
        .uid(spec.uid)
        .description(spec.description)
        .tags(["netapp-toolkit"])
        .refresh("30s")
        .time("now-1h", "now")
        .timezone("browser")
        .with_variable(dashboard.DatasourceVariable("datasource").label("Data source").type("prometheus"))
    )
    for v in spec.variables:
        board = board.with_variable(
            dashboard.QueryVariable(v.name)
            .label(v.label)
            .datasource(source)
            .query(v.query)
            .refresh(VariableRefresh.ON_TIME_RANGE_CHANGED)
            .multi(True)
            .include_all(True)
            .all_value(".*")
        )
    for p in spec.panels:
        panel = timeseries.Panel().title(p.title).unit(p.unit).datasource(source).span(12).height(8)
        panel = panel.legend(
            common.VizLegendOptions()
            .show_legend(True)
            .display_mode(LegendDisplayMode.LIST)
            .placement(LegendPlacement.BOTTOM)
            .calcs([])
        ).tooltip(common.VizTooltipOptions().mode(TooltipDisplayMode.MULTI).sort(SortOrder.NONE))
        if p.description:
            panel = panel.description(p.description)
        for i, q in enumerate(p.queries):
            panel = panel.with_target(prometheus.Dataquery().expr(q.expr).legend_format(q.legend).ref_id(chr(65 + i)))
        board = board.with_panel(panel)
    return json.loads(json.dumps(board.build(), cls=JSONEncoder))


def render(spec: DashboardSpec) -> str:
    """The file's text: sorted keys and a final newline, so regenerating gives the same bytes."""
    return json.dumps(build(spec), indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if a file differs from what the code makes")
    args = parser.parse_args(argv)
    stale = []
    for spec in DASHBOARDS:
        path = OUT / f"{spec.uid}.json"
        text = render(spec)
        if path.exists() and path.read_text() == text:
            continue
        stale.append(path)
        if not args.check:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    if args.check and stale:
        print(f"stale: {', '.join(str(p.relative_to(ROOT)) for p in stale)}: run python -m tools.dashboards")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
