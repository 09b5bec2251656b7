#!/usr/bin/env bash
# Validate everything under deploy/ with real tools. Called by .ci/run; runs anywhere with
# python3 and Debian's apt (as root, or with sudo).
#
#   promtool             (Debian package `prometheus`)  Prometheus configs, alert rules, the
#                        rules' unit tests, and every PromQL query of the dashboard and of the
#                        Prometheus adapter rules
#   kubernetes-validate  (PyPI, ships the Kubernetes JSON schemas)  every manifest, strict, for
#                        each version in K8S_VERSIONS; also the `kubectl kustomize` rendering
#                        when kubectl is on the machine
#   docker compose       (the compose plugin if present, else Debian's `docker-compose`)
#                        `config`; plus the compose-spec JSON schema (check-jsonschema, PyPI)
#   dockerfile           (PyPI, BuildKit's Dockerfile parser)  the Dockerfile
#   envoy-data-plane     (PyPI, Envoy's v3 API as Python classes)  the gateway's Envoy config
#   tools/check_deploy.py  structure and cross-file consistency (dashboard layout and queries,
#                        ports, probes, drain vs. grace period, selectors, HPA vs. adapter,
#                        Envoy vs. Services)
#
# Installation is idempotent: missing Debian packages are installed once; the Python tools live
# in a virtualenv under $DYNASERVE_DEPLOY_TOOLS (default ~/.cache/dynaserve-deploy-tools),
# rebuilt only when tools/requirements.txt changes. Nothing is written inside the repository.
set -euo pipefail

deploy="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
tools="${DYNASERVE_DEPLOY_TOOLS:-${XDG_CACHE_HOME:-$HOME/.cache}/dynaserve-deploy-tools}"
read -r -a k8s_versions <<<"${K8S_VERSIONS:-1.30.0 1.37.0}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

as_root() {
    if [ "$(id -u)" = 0 ]; then
        "$@"
    elif command -v sudo >/dev/null 2>&1; then
        sudo "$@"
    else
        echo "deploy/validate.sh: need root to run: $*" >&2
        return 1
    fi
}

# ---------------------------------------------------------------------------------- install
apt_packages=()
command -v promtool >/dev/null 2>&1 || apt_packages+=(prometheus)
if docker compose version >/dev/null 2>&1; then
    compose=(docker compose)
else
    command -v docker-compose >/dev/null 2>&1 || apt_packages+=(docker-compose)
    compose=(docker-compose)
fi
if [ "${#apt_packages[@]}" -gt 0 ]; then
    echo "==> installing Debian packages: ${apt_packages[*]}"
    # Installing `prometheus` must not start a Prometheus server on this machine: deny service
    # starts for the duration of the install unless a policy is already in place.
    policy_added=0
    if [ ! -e /usr/sbin/policy-rc.d ]; then
        printf '#!/bin/sh\nexit 101\n' | as_root tee /usr/sbin/policy-rc.d >/dev/null
        as_root chmod 0755 /usr/sbin/policy-rc.d
        policy_added=1
    fi
    as_root apt-get update -qq || echo "apt-get update reported errors; trying the install anyway" >&2
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        "${apt_packages[@]}" >"$work/apt.log" 2>&1 || { cat "$work/apt.log" >&2; exit 1; }
    [ "$policy_added" = 0 ] || as_root rm -f /usr/sbin/policy-rc.d
fi

requirements="$deploy/tools/requirements.txt"
want="$(sha256sum "$requirements" | cut -d' ' -f1)"
if [ ! -x "$tools/venv/bin/python" ] || [ "$(cat "$tools/venv/.requirements.sha256" 2>/dev/null)" != "$want" ]; then
    echo "==> installing Python tools into $tools/venv"
    mkdir -p "$tools"
    python3 -m venv --clear "$tools/venv"
    "$tools/venv/bin/pip" install -q --disable-pip-version-check -r "$requirements"
    echo "$want" >"$tools/venv/.requirements.sha256"
fi
py="$tools/venv/bin/python"
bin="$tools/venv/bin"

echo "==> tools: $(promtool --version 2>&1 | head -1); ${compose[*]} $("${compose[@]}" version --short 2>/dev/null || true);" \
    "kubernetes-validate $("$bin/kubernetes-validate" --version 2>&1 | tail -1); check-jsonschema $("$bin/check-jsonschema" --version 2>&1 | awk '{print $NF}')"

# ----------------------------------------------------------------------------------- checks
passed=0
failed=0
# check NAME COMMAND...: run one check, show its output on failure, count it.
check() {
    local name="$1"
    shift
    if "$@" >"$work/out" 2>&1; then
        passed=$((passed + 1))
        printf 'ok   %s\n' "$name"
    else
        failed=$((failed + 1))
        printf 'FAIL %s\n' "$name"
        sed 's/^/     /' "$work/out"
    fi
}
structure() { "$py" "$deploy/tools/check_deploy.py" "$deploy" "$work/gen" "$1"; }

cd "$deploy"
k8s_files=(k8s/deployment.yaml k8s/service.yaml k8s/envoy.yaml k8s/hpa.yaml k8s/pdb.yaml)

check "Dockerfile: BuildKit parser, stages, cached dependency layer, non-root, HEALTHCHECK" structure dockerfile
check "Grafana dashboard: loads, layout, datasource, variables, required panels" structure dashboard
check "PromQL of dashboard and adapter rules extracted" structure promql
check "promtool check rules: every dashboard and adapter query parses" \
    promtool check rules "$work/gen/generated-queries.rules.yml"
check "promtool check rules: alert rules" promtool check rules prometheus/rules/dynaserve.rules.yml
check "promtool test rules: alert unit tests" promtool test rules prometheus/tests/dynaserve.rules.test.yml
check "Prometheus Kubernetes config: discovery block and relabelling for the adapter" structure prometheus-k8s
check "promtool check config: compose Prometheus config (with its rules)" \
    promtool check config "$work/gen/prometheus.promtool.yml"
check "promtool check config: Kubernetes Prometheus config (discovery swapped for static targets)" \
    promtool check config "$work/gen/prometheus-kubernetes.promtool.yml"
for v in "${k8s_versions[@]}"; do
    check "kubernetes-validate --strict, Kubernetes $v: ${k8s_files[*]}" \
        "$bin/kubernetes-validate" --strict --quiet -k "$v" "${k8s_files[@]}"
done
if command -v kubectl >/dev/null 2>&1 && kubectl kustomize k8s >"$work/kustomized.yaml" 2>"$work/kustomize.err"; then
    check "kubectl kustomize k8s + kubernetes-validate --strict ${k8s_versions[-1]}" \
        "$bin/kubernetes-validate" --strict --quiet -k "${k8s_versions[-1]}" "$work/kustomized.yaml"
elif command -v kubectl >/dev/null 2>&1; then
    check "kubectl kustomize k8s" bash -c 'cat "$1"; exit 1' _ "$work/kustomize.err"
else
    echo "skip kubectl kustomize (no kubectl here; check_deploy.py compares the resource list instead)"
fi
check "Kubernetes cross-checks: probes, grace > preStop + drain, selectors, HPA vs adapter, Envoy vs Services" structure k8s
check "Envoy gateway config parsed into Envoy's v3 API types (envoy-data-plane)" structure envoy
check "${compose[*]} config" "${compose[@]}" --project-directory "$deploy" -f compose.yaml config -q
check "compose-spec schema (check-jsonschema vendor.compose-spec)" \
    "$bin/check-jsonschema" --builtin-schema vendor.compose-spec compose.yaml
check "compose cross-checks: mounts exist, ports, scrape target, datasource, stop grace" structure compose
check "metric names used by dashboard, alerts and adapter (compared with the server by tests/deploy_metrics.rs)" structure names
cat "$work/out"

echo "deploy: $passed passed, $failed failed"
[ "$failed" = 0 ]
