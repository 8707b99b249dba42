"""Build (and push) the images the chart deploys, with whichever builder is here: docker, buildah or podman.

    python tools/images.py [--push] [--registry R] [NAME...]   # default: netapp netapp-tracking control-plane
    python tools/images.py --sizes [NAME...]                   # image and layer sizes (MB)

NAME: netapp, netapp-tracking, netapp-h264, netapp-webrtc, control-plane, gpu, gpu-tensorrt (`make images` runs this).

The bases are Debian bookworm root file systems with python3 made by mmdebstrap (smaller than python:3.11-slim, and
buildable where no registry can be reached), cached per machine under ~/.cache/netapp/images keyed by its inputs;
PYTHON_IMAGE and BUILD_IMAGE (e.g. python:3.11-slim-bookworm, both) use registry images instead. See docs/images.md.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REGISTRY = "ghcr.io/netapp-toolkit"
INSTALL_HINT = "apt-get install buildah mmdebstrap (make system-deps), or a docker daemon"
CACHE = Path(os.environ.get("NETAPP_IMAGE_CACHE", Path.home() / ".cache" / "netapp" / "images"))

# The bases: what mmdebstrap is asked for. Any change here makes a new cache key, hence new bases. The runtime base
# has python3 alone; the build base adds venv (pip) and binutils (strip), which stay in the build stages.
BASE_SUITE = "bookworm"
RUNTIME_PACKAGES = ("python3", "libstdc++6", "ca-certificates", "netbase", "passwd")  # libstdc++: the wheels
BUILD_PACKAGES = (*RUNTIME_PACKAGES, "python3-venv", "binutils")
BASE_MIRRORS = (
    "deb http://deb.debian.org/debian bookworm main",
    "deb http://deb.debian.org/debian bookworm-updates main",
    "deb http://deb.debian.org/debian-security bookworm-security main",
)
BASE_OPTIONS = (
    "--variant=essential",  # no apt: nothing installs packages at run time
    "--hook-dir=/usr/share/mmdebstrap/hooks/merged-usr",  # else usrmerge and perl come along (45 MB)
    "--dpkgopt=path-exclude=/usr/share/man/*",
    "--dpkgopt=path-exclude=/usr/share/doc/*",
    "--dpkgopt=path-include=/usr/share/doc/*/copyright",
    "--dpkgopt=path-exclude=/usr/share/locale/*",
    "--dpkgopt=path-exclude=/usr/share/info/*",
    "--dpkgopt=path-exclude=/usr/lib/x86_64-linux-gnu/gconv/*",  # iconv's charsets (8 MB): Python has its own codecs
    # Perl (9 MB) ran the packages' install scripts; with no apt or dpkg run in an image nothing runs it again.
    '--customize-hook=rm -rf "$1"/usr/lib/x86_64-linux-gnu/perl-base "$1"/usr/bin/perl "$1"/usr/bin/perl5.36.0',
)
BASE_ENV = {"LANG": "C.UTF-8"}
BASE_CMD = ["python3"]
BASES = {"runtime": RUNTIME_PACKAGES, "build": BUILD_PACKAGES}


@dataclass(frozen=True)
class Image:
    name: str
    dockerfile: str
    target: str | None
    repository: str
    tag_suffix: str = ""
    build_args: tuple[tuple[str, str], ...] = ()


TENSORRT = (("TENSORRT", "1"),)  # the GPU image's build argument that adds TensorRT's libraries
IMAGES = {
    i.name: i
    for i in (
        Image("netapp", "docker/netapp.Dockerfile", "netapp", "netapp"),
        Image("netapp-tracking", "docker/netapp.Dockerfile", "netapp-tracking", "netapp", "-tracking"),
        Image("netapp-h264", "docker/netapp.Dockerfile", "netapp", "netapp", "-h264", build_args=(("H264", "1"),)),
        # aiortc and PyAV (the `webrtc` extra): /camera and POST /webrtc/offer in a cluster
        Image(
            "netapp-webrtc", "docker/netapp.Dockerfile", "netapp", "netapp", "-webrtc", build_args=(("WEBRTC", "1"),)
        ),
        Image("control-plane", "docker/control-plane.Dockerfile", None, "control-plane"),
        # A few GB of NVIDIA's wheels on the same base (docs/images.md): built on request, not in the default set.
        # GPU_CONSTRAINTS from the environment pins versions (the CUDA 12 build); TensorRT needs NVIDIA's index.
        Image("gpu", "docker/netapp.Dockerfile", "netapp-gpu", "netapp", "-gpu"),
        Image("gpu-tensorrt", "docker/netapp.Dockerfile", "netapp-gpu", "netapp", "-gpu-tensorrt", TENSORRT),
    )
}
DEFAULT = ("netapp", "netapp-tracking", "control-plane")
PASSED_ARGS = ("GPU_CONSTRAINTS",)  # build arguments taken from the environment when set (`make images GPU_...=`)


def app_version() -> str:
    text = (ROOT / "charts" / "netapp-toolkit" / "Chart.yaml").read_text()
    return re.search(r'^appVersion:\s*"?([^"\s]+)"?', text, re.M).group(1)


def reference(image: Image, registry: str = REGISTRY) -> str:
    return f"{registry}/{image.repository}:{app_version()}{image.tag_suffix}"


def run(*argv: str, capture: bool = False) -> str:
    result = subprocess.run(argv, check=True, text=True, stdout=subprocess.PIPE if capture else None)
    return result.stdout if capture else ""


def works(*argv: str) -> bool:
    try:
        return subprocess.run(argv, capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def find_builder() -> str | None:
    """docker when its daemon answers, else buildah, else podman; BUILDER=... picks one."""
    if os.environ.get("BUILDER"):
        return os.environ["BUILDER"]
    if works("docker", "info"):
        return "docker"
    if works("buildah", "--version"):
        return "buildah"
    if works("podman", "info"):
        return "podman"
    return None


def base_key(kind: str) -> str:
    spec = [BASE_SUITE, BASES[kind], BASE_MIRRORS, BASE_OPTIONS, BASE_ENV, BASE_CMD]
    return hashlib.sha256(json.dumps(spec).encode()).hexdigest()[:12]


def image_exists(builder: str, ref: str) -> bool:
    if builder == "buildah":
        return works("buildah", "inspect", "--type", "image", ref)
    return works(builder, "image", "inspect", ref)


def debian_base(builder: str, kind: str) -> str:
    """A base ("runtime" or "build") as a local image, made once per machine (its tarball kept in CACHE)."""
    key = base_key(kind)
    ref = f"localhost/netapp-toolkit-{kind}:{key}"
    if image_exists(builder, ref):
        return ref
    tarball = CACHE / f"{kind}-{key}.tar"
    if not tarball.exists():
        if not shutil.which("mmdebstrap"):
            raise SystemExit(f"no base image: set PYTHON_IMAGE and BUILD_IMAGE, or {INSTALL_HINT}")
        CACHE.mkdir(parents=True, exist_ok=True)
        part = tarball.with_suffix(".part.tar")
        packages = f"--include={','.join(BASES[kind])}"
        run("nice", "-n", "10", "mmdebstrap", *BASE_OPTIONS, packages, BASE_SUITE, str(part), *BASE_MIRRORS)
        part.replace(tarball)
        for stale in CACHE.glob(f"{kind}-*.tar"):  # an older key's: its inputs changed
            if stale != tarball:
                stale.unlink()
    if builder == "buildah":
        container = run("buildah", "from", "scratch", capture=True).strip()
        run("buildah", "add", "--quiet", container, str(tarball), "/")
        env = [x for k, v in BASE_ENV.items() for x in ("--env", f"{k}={v}")]
        run("buildah", "config", *env, "--cmd", json.dumps(BASE_CMD), container)
        run("buildah", "commit", "--rm", "--quiet", container, ref)
    else:
        changes = [f"--change=ENV {k}={v}" for k, v in BASE_ENV.items()] + [f"--change=CMD {json.dumps(BASE_CMD)}"]
        run(builder, "import", *changes, str(tarball), ref)
    return ref


def bases(builder: str) -> dict[str, str]:
    """Build arg -> base image: PYTHON_IMAGE and BUILD_IMAGE from the environment, else the mmdebstrap bases."""
    return {
        "PYTHON_IMAGE": os.environ.get("PYTHON_IMAGE") or debian_base(builder, "runtime"),
        "BUILD_IMAGE": os.environ.get("BUILD_IMAGE") or debian_base(builder, "build"),
    }


def ca_bundle() -> str | None:
    """The CA bundle pip needs in the build (a TLS-intercepting proxy's CA lives in the host's bundle)."""
    candidates = (os.environ.get("PIP_CERT"), os.environ.get("SSL_CERT_FILE"), "/etc/ssl/certs/ca-certificates.crt")
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return candidate
    return None


def build_command(builder: str, image: Image, build_args: dict[str, str], ref: str) -> list[str]:
    argv = [builder, "bud", "--isolation", "chroot", "--layers"] if builder == "buildah" else [builder, "build"]
    argv += ["-f", image.dockerfile, "-t", ref]
    if image.target:
        argv += ["--target", image.target]
    for name, value in build_args.items():
        argv += ["--build-arg", f"{name}={value}"]
    if ca_bundle():
        argv += ["--secret", f"id=ca,src={ca_bundle()}"]
    return [*argv, "."]


def build(names: list[str], builder: str, registry: str = REGISTRY) -> dict[str, str]:
    """Build the named images; returns name -> image reference."""
    refs, debian = {}, bases(builder) if names else {}
    passed = {k: os.environ[k] for k in PASSED_ARGS if os.environ.get(k)}
    for name in names:
        image = IMAGES[name]
        refs[name] = reference(image, registry)
        argv = build_command(builder, image, {**debian, **passed, **dict(image.build_args)}, refs[name])
        subprocess.run(["nice", "-n", "10", *argv], cwd=ROOT, check=True)
    return refs


# Runs a command in a mounted image root as a container would: its own mount namespace, the root read-only, a tmpfs
# on /tmp, the image's user, environment and entrypoint, the host's network. `buildah run --isolation chroot` cannot
# keep the root read-only (it writes /run/.containerenv into it) and podman cannot start containers on these VMs.
_CHROOT = """
set -eu
root="$1"; shift
mount --bind "$root" "$root"
mount -t proc proc "$root/proc"
mount --rbind /dev "$root/dev"
mount -t tmpfs -o mode=1777 tmpfs "$root/tmp"
while [ "$1" != -- ]; do mkdir -p "$root$2"; mount --bind -o ro "$1" "$root$2"; shift 2; done; shift
mount -o remount,bind,ro "$root"
exec "$@"
"""


def image_config(builder: str, ref: str) -> dict:
    """The image's OCI config: User, Env, Entrypoint, Cmd, WorkingDir."""
    if builder == "buildah":
        return json.loads(run("buildah", "inspect", "--type", "image", ref, capture=True))["OCIv1"]["config"]
    config = json.loads(run(builder, "image", "inspect", ref, capture=True))[0]["Config"]
    return {k: config.get(k) for k in ("User", "Env", "Entrypoint", "Cmd", "WorkingDir")}


@contextmanager
def container(
    builder: str,
    ref: str,
    args: Sequence[str] | None = None,
    mounts: Mapping[str, str] | None = None,
    env: Mapping[str, str] | None = None,
    entrypoint: Sequence[str] | None = None,
) -> Iterator[list[str]]:
    """The command line that runs image `ref` (its entrypoint with `args`, else its CMD) read-only, as its user,
    on the host's network, with host folders `mounts` (host -> container path) read-only and `env` added."""
    mounts, env = dict(mounts or {}), dict(env or {})
    config = image_config(builder, ref)
    if entrypoint is None:
        entrypoint = config.get("Entrypoint") or []
        args = args if args is not None else config.get("Cmd") or []
    argv = [*entrypoint, *(args or [])]
    if builder != "buildah":
        options = [f"--volume={host}:{inside}:ro" for host, inside in mounts.items()]
        options += [f"--env={k}={v}" for k, v in env.items()]
        if entrypoint:
            options += [f"--entrypoint={entrypoint[0]}"]
        yield [builder, "run", "--rm", "--read-only", "--tmpfs=/tmp", "--network=host", *options, ref, *argv[1:]]
        return
    name = run("buildah", "from", "--quiet", ref, capture=True).strip()
    try:
        root = Path(run("buildah", "mount", name, capture=True).strip())
        for inside in mounts.values():  # an absolute link in the image would lead the mount out of it
            parts = Path(inside).relative_to("/").parts
            if any((root.joinpath(*parts[: i + 1])).is_symlink() for i in range(len(parts))):
                raise ValueError(f"mount target {inside} goes through a link in the image")
        environment = ["env", "-i", *(config.get("Env") or []), *(f"{k}={v}" for k, v in env.items())]
        inner = ["chroot", f"--userspec={config.get('User') or '0:0'}", str(root), *environment, *argv]
        binds = [x for host, inside in mounts.items() for x in (host, inside)]
        yield ["unshare", "--mount", "--fork", "sh", "-c", _CHROOT, "chroot-run", str(root), *binds, "--", *inner]
    finally:
        subprocess.run(["buildah", "rm", name], capture_output=True, check=False)


def layer_sizes(builder: str, ref: str) -> list[tuple[int, str]]:
    """(bytes, the instruction that made it) for each layer, bottom up."""
    if builder != "buildah":
        out = run(builder, "history", "--no-trunc", "--format", "{{.Size}}\t{{.CreatedBy}}", ref, capture=True)
        return [(0, line) for line in reversed(out.splitlines())]  # docker prints human sizes; kept as text
    info = json.loads(run("buildah", "inspect", "--type", "image", ref, capture=True))
    diff_ids = info["OCIv1"]["rootfs"]["diff_ids"]
    history = [h for h in info["OCIv1"]["history"] if not h.get("empty_layer")]
    graph_root = json.loads(run("buildah", "info", capture=True))["store"]["GraphRoot"]
    layers = json.loads((Path(graph_root) / "overlay-layers" / "layers.json").read_text())
    size = {layer.get("diff-digest"): layer.get("diff-size", 0) for layer in layers}
    return [(size.get(d, 0), h.get("created_by", "")) for d, h in zip(diff_ids, history, strict=True)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    names_help = f"of {', '.join(IMAGES)} (default: {' '.join(DEFAULT)})"
    parser.add_argument("names", nargs="*", metavar="NAME", help=names_help)
    parser.add_argument("--registry", default=os.environ.get("REGISTRY", REGISTRY))
    parser.add_argument("--push", action="store_true", help="push the images after building them")
    parser.add_argument("--sizes", action="store_true", help="print image and layer sizes instead of building")
    args = parser.parse_args(argv)
    builder = find_builder()
    if builder is None:
        print(f"images: no image builder here; {INSTALL_HINT}", file=sys.stderr)
        return 1
    names = args.names or list(DEFAULT)
    unknown = set(names) - set(IMAGES)
    if unknown:
        parser.error(f"no image {', '.join(sorted(unknown))}; the images: {', '.join(IMAGES)}")
    if args.sizes:
        for name in names:
            layers = layer_sizes(builder, reference(IMAGES[name], args.registry))
            print(f"{name}: {sum(s for s, _ in layers) / 1e6:.0f} MB")
            for size, created_by in layers:
                print(f"  {size / 1e6:8.1f} MB  {created_by[-100:]}")
        return 0
    refs = build(names, builder, args.registry)
    for ref in refs.values():
        if args.push:
            run(builder, "push", ref)
        print(ref)
    return 0


if __name__ == "__main__":
    sys.exit(main())
