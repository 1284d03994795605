#!/usr/bin/env bash
# make docker-test: build the CPU image and run the service smoke test (docker/smoke.py) inside it.
#
# * dockerd: Debian's docker.io (installed when missing); started here, in the background, when no
#   daemon answers (log in $DOCKERD_LOG), and stopped again at the end if this script started it.
# * The base image (the Dockerfile's ARG BASE) is pulled; when that fails (no registry reachable),
#   a Debian root made with `debootstrap --variant=minbase` of the same release, with the release's
#   -updates and -security sources and no apt caches, stands in for it: imported once as
#   depthview/<release>-debootstrap (never under the real image's name) and passed as
#   --build-arg BASE.
# * The build uses BuildKit (the Dockerfiles mount the extra CA certificates as a secret): through
#   docker buildx where the client has it, else a client that still has BuildKit built in (Debian's
#   docker.io 20.10: DOCKER_BUILDKIT=1).
# * The build uses the host's network (apt, PyPI and npm as the host reaches them); the container
#   runs with no network at all: the image's own `depthview serve` (its CMD) and the smoke test,
#   run in it with `docker exec`, talk over the container's loopback. It is removed with its
#   anonymous /data volume.
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE=${DOCKER_IMAGE:-depthview:cpu}
DOCKERFILE=${DOCKERFILE:-docker/Dockerfile.cpu}
DEBIAN_MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
DEBIAN_SECURITY_MIRROR=${DEBIAN_SECURITY_MIRROR:-http://deb.debian.org/debian-security}
DOCKERD_LOG=${DOCKERD_LOG:-/tmp/depthview-dockerd.log}
SUDO=$( [ "$(id -u)" -eq 0 ] || echo sudo )
say() { echo "docker-test: $*"; }

apt_install() {  # packages whose commands are missing
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@"
}

# --- the daemon -------------------------------------------------------------------------------
command -v dockerd >/dev/null 2>&1 || { say "installing docker.io"; apt_install docker.io; }
started_dockerd=""
if ! docker info >/dev/null 2>&1; then
  say "starting dockerd (log: $DOCKERD_LOG)"
  $SUDO dockerd >"$DOCKERD_LOG" 2>&1 &
  started_dockerd=$!
  for _ in $(seq 60); do docker info >/dev/null 2>&1 && break; sleep 1; done
  docker info >/dev/null 2>&1 || { say "dockerd did not start:"; tail -20 "$DOCKERD_LOG"; exit 1; }
fi
container=""
secret=$(mktemp /tmp/depthview-ca.XXXXXX)
cleanup() {
  [ -z "$container" ] || docker rm -f -v "$container" >/dev/null 2>&1 || true
  rm -f "$secret"
  if [ -n "$started_dockerd" ]; then
    say "stopping the dockerd it started"; $SUDO kill "$started_dockerd" || true; wait "$started_dockerd" || true
  fi
}
trap cleanup EXIT
docker version --format 'docker-test: client {{.Client.Version}}, server {{.Server.Version}}'

# --- the base image ---------------------------------------------------------------------------
base=$(sed -n 's/^ARG BASE=//p' "$DOCKERFILE" | head -1)
[ -n "$base" ] || { say "$DOCKERFILE has no ARG BASE=IMAGE"; exit 1; }
registry_image() { [ "$(docker image inspect -f '{{len .RepoDigests}}' "$1" 2>/dev/null || echo 0)" -gt 0 ]; }
if registry_image "$base"; then
  say "base image $base is present"
elif docker pull "$base"; then
  say "pulled $base"
else
  case "$base" in
    debian:*) release=${base#debian:}; release=${release%%-*} ;;
    *) say "cannot pull $base and no Debian root stands in for it"; exit 1 ;;
  esac
  if docker image inspect "$base" >/dev/null 2>&1; then
    say "ignoring the local $base: it came from no registry (an older docker-test's stand-in? docker rmi $base)"
  fi
  standin=depthview/$release-debootstrap
  if docker image inspect "$standin" >/dev/null 2>&1; then
    say "no registry: $standin stands in for $base"
  else
    command -v debootstrap >/dev/null 2>&1 || { say "installing debootstrap"; apt_install debootstrap; }
    root=$(mktemp -d /tmp/depthview-rootfs.XXXXXX)
    say "no registry: debootstrap --variant=minbase $release into $root, imported as $standin"
    $SUDO debootstrap --variant=minbase "$release" "$root" "$DEBIAN_MIRROR" >"$root.log" 2>&1 \
      || { tail -20 "$root.log"; exit 1; }
    # the sources of Debian's own image (deb822): the release, its updates and its security fixes
    $SUDO rm -f "$root/etc/apt/sources.list"
    printf '%s\n' "Types: deb" "URIs: $DEBIAN_MIRROR" "Suites: $release $release-updates" "Components: main" \
      "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg" "" \
      "Types: deb" "URIs: $DEBIAN_SECURITY_MIRROR" "Suites: $release-security" "Components: main" \
      "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg" \
      | $SUDO tee "$root/etc/apt/sources.list.d/debian.sources" >/dev/null
    # no apt caches nor lists (the build's apt-get update fetches the lists)
    $SUDO find "$root/var/lib/apt/lists" "$root/var/cache/apt" -type f -delete
    $SUDO tar -C "$root" -c . | docker import -c 'CMD ["bash"]' - "$standin"
    $SUDO rm -rf "$root" "$root.log"
  fi
  base=$standin
fi

# BuildKit: buildx, or a client with BuildKit built in (Docker before 23 with DOCKER_BUILDKIT=1)
buildkit=""
for client in docker /usr/bin/docker; do
  command -v "$client" >/dev/null 2>&1 || continue
  major=$("$client" version -f '{{.Client.Version}}' 2>/dev/null | cut -d. -f1)
  if "$client" buildx version >/dev/null 2>&1 || [ "${major:-99}" -lt 23 ]; then buildkit=$client; break; fi
done
[ -n "$buildkit" ] || { say "no docker client here builds with BuildKit: install docker buildx"; exit 1; }

# --- build and smoke test -----------------------------------------------------------------------
say "building $IMAGE from $DOCKERFILE"
t0=$(date +%s)
# CA certificates the host trusts beyond Debian's (a TLS-inspecting proxy between it and the
# registries): npm and pip in the build trust them too (a BuildKit secret: kept out of the image).
python3 - "${SSL_CERT_FILE:-/etc/ssl/certs/ca-certificates.crt}" >"$secret" <<'PY'
import glob, re, sys
pem = re.compile(r"-----BEGIN CERTIFICATE-----.*?-----END CERTIFICATE-----", re.S)
try:
    host = pem.findall(open(sys.argv[1]).read())
except OSError:
    host = []
debian = {"".join(c.split()) for f in glob.glob("/usr/share/ca-certificates/**/*.crt", recursive=True)
          for c in pem.findall(open(f).read())}
print("\n".join(c for c in host if "".join(c.split()) not in debian))
PY
extra=$(grep -c 'BEGIN CERT' "$secret" || true)
[ "$extra" -eq 0 ] || say "passing $extra CA certificate(s) the host trusts beyond Debian's"
DOCKER_BUILDKIT=1 "$buildkit" build --network host --build-arg BASE="$base" --secret id=ca,src="$secret" \
  -f "$DOCKERFILE" -t "$IMAGE" .
say "built $IMAGE in $(( $(date +%s) - t0 )) s: $(docker image inspect -f '{{.Size}}' "$IMAGE" | numfmt --to=iec) "

container=depthview-smoke-$$
docker run -d --name "$container" --network none "$IMAGE" >/dev/null
say "running docker/smoke.py in $container (the image's CMD serves on its loopback)"
if docker exec -i "$container" /app/.venv/bin/python - --url http://127.0.0.1:8000 <docker/smoke.py; then
  status=0
else
  status=$?
fi
logs=$(docker logs "$container" 2>&1)
if grep -q -E "Traceback|ERROR" <<<"$logs"; then say "the service logged errors"; status=1; fi
if [ "$status" -ne 0 ]; then say "service log:"; echo "$logs" | tail -40; say "FAILED"; exit "$status"; fi
grep -E "renderer|Uvicorn running" <<<"$logs" | head -5 || true
say "passed"
