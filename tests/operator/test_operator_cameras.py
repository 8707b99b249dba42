"""A NetApp with cameras (`spec.sources`): its replicas share them through Leases, so its pods get --camera-leases,
their NetApp's name and an account of their own, bound to a Role on exactly those Leases (pure rendering)."""

from __future__ import annotations

from netapp_operator.cameras import CAMERA_KINDS
from netapp_operator.render import render, render_standby
from netapp_operator.spec import parse

from netapp.server.sources.leases import lease_name
from tests.operator.test_operator_render import UID, netapp, pool

CAMERAS = [{"name": "door", "url": "rtsp://10.0.0.5/s"}, {"name": "Yard_2", "url": "rtsp://10.0.0.6/s"}]


def children(**spec) -> list[dict]:
    na = netapp(**spec)
    return render(na, parse(na["spec"]), pool())


def pod_of(made: list[dict]) -> dict:
    [deployment] = [c for c in made if c["kind"] == "Deployment"]
    return deployment["spec"]["template"]["spec"]


def test_a_netapp_with_cameras_gets_leases_its_name_and_an_account_of_its_own():
    made = children(sources=CAMERAS, replicas=3)
    pod = pod_of(made)
    [container] = pod["containers"]
    args = container["args"]
    assert args[args.index("--camera-leases") + 1] == "robots"  # its own namespace
    env = {e["name"]: e for e in container["env"]}
    assert env["NETAPP_NAME"]["value"] == "det"  # the Leases' prefix, as the Role names them
    assert env["POD_NAME"]["valueFrom"] == {"fieldRef": {"fieldPath": "metadata.name"}}
    assert pod["serviceAccountName"] == "det-cameras" and pod["automountServiceAccountToken"] is True

    by_kind = {c["kind"]: c for c in made if c["kind"] in CAMERA_KINDS}
    assert set(by_kind) == set(CAMERA_KINDS)
    for child in by_kind.values():
        assert child["metadata"]["name"] == "det-cameras" and child["metadata"]["namespace"] == "robots"
        assert child["metadata"]["ownerReferences"][0]["uid"] == UID  # adopted: it goes with the NetApp
    assert by_kind["ServiceAccount"]["automountServiceAccountToken"] is False  # only the camera pods mount it
    # Least privilege: create (RBAC cannot name what does not exist yet), and get/patch of this NetApp's Leases only,
    # named as the netapp names them
    assert by_kind["Role"]["rules"] == [
        {"apiGroups": ["coordination.k8s.io"], "resources": ["leases"], "verbs": ["create"]},
        {
            "apiGroups": ["coordination.k8s.io"],
            "resources": ["leases"],
            "resourceNames": sorted([lease_name("det", "door"), lease_name("det", "Yard_2")]),
            "verbs": ["get", "patch"],
        },
    ]
    binding = by_kind["RoleBinding"]
    assert binding["roleRef"] == {"apiGroup": "rbac.authorization.k8s.io", "kind": "Role", "name": "det-cameras"}
    assert binding["subjects"] == [{"kind": "ServiceAccount", "name": "det-cameras", "namespace": "robots"}]


def test_without_cameras_a_netapp_mounts_no_token_and_gets_no_account():
    made = children()
    pod = pod_of(made)
    assert pod["automountServiceAccountToken"] is False and "serviceAccountName" not in pod
    assert "--camera-leases" not in pod["containers"][0]["args"]
    assert not [c for c in made if c["kind"] in CAMERA_KINDS]


def test_a_warm_standby_shares_the_netapps_account_rather_than_rendering_another():
    na = netapp(sources=CAMERAS, standby={"replicas": 1})
    warm = render_standby(na, parse(na["spec"]), pool("cloud"))
    assert {c["kind"] for c in warm} == {"Deployment", "Service", "NetworkPolicy"}
    assert pod_of(warm)["serviceAccountName"] == "det-cameras"
