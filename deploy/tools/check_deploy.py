#!/usr/bin/env python3
"""Structural and cross-file checks of the deployment files (run by deploy/validate.sh).

The schema-level checks are done by real tools in validate.sh (promtool, kubernetes-validate,
docker compose / compose-spec schema). This script covers what those tools cannot see:

  dashboard      Grafana dashboard JSON: loads, panel ids unique, grid layout inside 24 columns
                 without overlaps, every query uses the templated Prometheus datasource and only
                 defined variables, the required panels exist.
  promql         Writes every PromQL expression of the dashboard and the Prometheus adapter
                 rules into a rules file, so validate.sh can parse them with promtool.
  prometheus-k8s Rewrites prometheus-kubernetes.yml for promtool (whose Debian build lacks
                 Kubernetes discovery) and checks the discovery block itself.
  compose        Bind-mount sources and the build context exist, the scrape target and the
                 Grafana datasource point at compose services and ports.
  dockerfile     Parsed with BuildKit's own parser (python package `dockerfile`): multi-stage,
                 dependency layer before the sources, non-root runtime, HEALTHCHECK, ports;
                 every RUN line is valid shell.
  k8s            Probes, drain vs. grace period, selectors, HPA target and adapter metric,
                 Envoy clusters vs. Services, kustomization resource list.
  envoy          The gateway's Envoy configuration parsed into Envoy's v3 API types.
  ports          The same HTTP and gRPC ports in the Dockerfile, compose, Kubernetes and the
                 Prometheus configs.

Usage: check_deploy.py DEPLOY_DIR OUT_DIR CHECK...   (prints one line per check, exit 1 on any
failure). OUT_DIR receives generated files for promtool.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import yaml

HTTP_PORT = 8080
GRPC_PORT = 50051
# After the drain deadline the server gives connections this long to close before it exits
# (CLOSE_GRACE in crates/server/src/server.rs).
SERVER_CLOSE_GRACE_S = 5.0
# Header the clients send so that the gateway routes all calls of a session to one pod.
AFFINITY_HEADER = "x-dynaserve-affinity"
GRAFANA_BUILTINS = {"__rate_interval", "__interval", "__range", "__interval_ms", "__range_s"}
METRIC_RE = re.compile(r"\bdynaserve_[a-z0-9_]+\b")


class CheckError(Exception):
    """A failed expectation about a deployment file."""


def expect(cond: bool, msg: str) -> None:
    if not cond:
        raise CheckError(msg)


def load_yaml_docs(path: Path) -> list[dict]:
    with path.open() as f:
        return [d for d in yaml.safe_load_all(f) if d is not None]


def parse_duration_s(text: str) -> float:
    m = re.fullmatch(r"(\d+(?:\.\d+)?)(ms|s|m)?", str(text).strip())
    expect(m is not None, f"cannot parse duration {text!r}")
    value, unit = float(m.group(1)), m.group(2) or "s"
    return value / 1000 if unit == "ms" else value * 60 if unit == "m" else value


# ----------------------------------------------------------------------------------- dashboard


REQUIRED_PANELS = {
    # what the dashboard must show -> a regex one of its expressions must match
    "FPS as the rate of scene-steps": r"rate\(dynaserve_scene_steps_total",
    "step latency quantiles": r"histogram_quantile\(0\.99, .*dynaserve_forward_duration_seconds_bucket",
    "request latency quantiles": r"histogram_quantile\(0\.99, .*dynaserve_request_duration_seconds_bucket",
    "queue wait quantiles": r"histogram_quantile\(0\.99, .*dynaserve_queue_wait_seconds_bucket",
    "batch size in scenes": r"dynaserve_batch_scenes_bucket",
    "batch size in objects": r"dynaserve_batch_objects_bucket",
    "active rollouts": r"dynaserve_active_rollouts",
    "rejections by reason": r"sum by \(reason\) \(rate\(dynaserve_request_failures_total",
}


def dashboard_exprs(dash: dict) -> list[tuple[str, str]]:
    out = []
    for panel in dash["panels"]:
        for t in panel.get("targets", []):
            out.append((f"panel {panel['id']} ({panel.get('title')}) {t.get('refId')}", t.get("expr", "")))
    return out


def check_dashboard(deploy: Path, out: Path) -> str:
    path = deploy / "grafana/dashboards/dynaserve.json"
    dash = json.loads(path.read_text())
    for key in ("uid", "title", "panels", "schemaVersion", "templating"):
        expect(key in dash, f"{path}: missing top-level key {key!r}")
    expect(isinstance(dash["schemaVersion"], int), "schemaVersion must be an integer")
    variables = {v["name"]: v for v in dash["templating"]["list"]}
    expect(variables.get("datasource", {}).get("type") == "datasource"
           and variables["datasource"].get("query") == "prometheus",
           "dashboard needs a `datasource` variable of Prometheus type")

    # The provisioned datasource must be the variable's default.
    ds_prov = load_yaml_docs(deploy / "grafana/provisioning/datasources/prometheus.yaml")[0]
    uids = {d["uid"] for d in ds_prov["datasources"]}
    expect(variables["datasource"]["current"]["value"] in uids,
           f"datasource variable default {variables['datasource']['current']['value']!r} is not a provisioned uid {uids}")
    dprov = load_yaml_docs(deploy / "grafana/provisioning/dashboards/dynaserve.yaml")[0]
    expect(dprov["providers"][0]["options"]["path"] == "/var/lib/grafana/dashboards",
           "dashboard provider path must match the compose mount")

    ids: set[int] = set()
    rects = []
    for panel in dash["panels"]:
        pid = panel.get("id")
        expect(isinstance(pid, int) and pid not in ids, f"panel id {pid!r} missing or duplicated")
        ids.add(pid)
        expect(panel.get("type") in {"row", "timeseries", "stat", "gauge", "bargauge", "table", "heatmap", "text"},
               f"panel {pid}: unknown type {panel.get('type')!r}")
        g = panel.get("gridPos", {})
        for k in ("x", "y", "w", "h"):
            expect(isinstance(g.get(k), int) and g[k] >= 0, f"panel {pid}: gridPos.{k} missing or negative")
        expect(g["w"] >= 1 and g["x"] + g["w"] <= 24, f"panel {pid}: gridPos outside the 24-column grid")
        for (oid, o) in rects:
            overlap = (g["x"] < o["x"] + o["w"] and o["x"] < g["x"] + g["w"]
                       and g["y"] < o["y"] + o["h"] and o["y"] < g["y"] + g["h"])
            expect(not overlap, f"panels {oid} and {pid} overlap")
        rects.append((pid, g))
        if panel["type"] == "row":
            continue
        expect(panel.get("title"), f"panel {pid}: no title")
        targets = panel.get("targets", [])
        expect(targets, f"panel {pid}: no queries")
        refs = [t.get("refId") for t in targets]
        expect(len(set(refs)) == len(refs), f"panel {pid}: duplicate refIds")
        for t in [panel] + targets:
            ds = t.get("datasource", {})
            expect(ds.get("type") == "prometheus" and ds.get("uid") == "${datasource}",
                   f"panel {pid}: must use the templated Prometheus datasource")
        for t in targets:
            expr = t.get("expr", "")
            expect(expr.strip(), f"panel {pid}: empty expression")
            for var in re.findall(r"\$\{?(\w+)", expr):
                expect(var in variables or var in GRAFANA_BUILTINS, f"panel {pid}: undefined variable ${var}")

    exprs = [e for _, e in dashboard_exprs(dash)]
    for what, pattern in REQUIRED_PANELS.items():
        expect(any(re.search(pattern, e) for e in exprs), f"dashboard shows no {what} (/{pattern}/)")
    return f"{len(dash['panels'])} panels, {len(exprs)} queries, {len(REQUIRED_PANELS)} required views present"


# -------------------------------------------------------------------------------------- promql


def grafana_to_promql(expr: str) -> str:
    expr = expr.replace("$__rate_interval", "1m").replace("$__interval", "1m").replace("$__range", "1h")
    expr = expr.replace("$instance", ".*").replace("$job", "dynaserve")
    return expr


def adapter_to_promql(query: str, series: str) -> str:
    return (query.replace("<<.Series>>", series)
            .replace("<<.LabelMatchers>>", 'namespace="default",pod=~"dynaserve-.*"')
            .replace("<<.GroupBy>>", "pod"))


def check_promql(deploy: Path, out: Path) -> str:
    dash = json.loads((deploy / "grafana/dashboards/dynaserve.json").read_text())
    rules = []
    for i, (_, expr) in enumerate(dashboard_exprs(dash)):
        rules.append({"record": f"dashboard:query_{i}", "expr": grafana_to_promql(expr)})
    values = load_yaml_docs(deploy / "k8s/prometheus-adapter/values.yaml")[0]
    for i, rule in enumerate(values["rules"]["custom"]):
        for key in ("seriesQuery", "resources", "name", "metricsQuery"):
            expect(key in rule, f"adapter rule {i}: missing {key}")
        series = re.match(r"[a-zA-Z_:][a-zA-Z0-9_:]*", rule["seriesQuery"]).group(0)
        expect(re.search(rule["name"]["matches"], series), f"adapter rule {i}: name.matches does not match {series}")
        rules.append({"record": f"adapter:series_{i}", "expr": rule["seriesQuery"]})
        rules.append({"record": f"adapter:query_{i}", "expr": adapter_to_promql(rule["metricsQuery"], series)})
    out.mkdir(parents=True, exist_ok=True)
    target = out / "generated-queries.rules.yml"
    target.write_text(yaml.safe_dump({"groups": [{"name": "generated", "rules": rules}]}, sort_keys=False))
    return f"wrote {len(rules)} expressions to {target} for promtool"


# ------------------------------------------------------------------------------ prometheus-k8s


def check_prometheus_k8s(deploy: Path, out: Path) -> str:
    src = deploy / "prometheus/prometheus-kubernetes.yml"
    cfg = load_yaml_docs(src)[0]
    roles = {"node", "service", "pod", "endpoints", "endpointslice", "ingress"}
    n = 0
    for job in cfg["scrape_configs"]:
        for sd in job.pop("kubernetes_sd_configs", []):
            expect(set(sd) <= {"role", "namespaces", "selectors", "api_server", "kubeconfig_file", "attach_metadata"},
                   f"job {job['job_name']}: unknown kubernetes_sd_configs keys {set(sd)}")
            expect(sd.get("role") in roles, f"job {job['job_name']}: bad role {sd.get('role')!r}")
            job.setdefault("static_configs", []).append({"targets": ["pod-ip.example:8080"]})
            n += 1
        kept = {r.get("target_label") for r in job.get("relabel_configs", [])}
        expect({"namespace", "pod"} <= kept, f"job {job['job_name']}: must keep namespace and pod labels for the adapter")
    cfg["rule_files"] = [str((deploy / "prometheus/rules").resolve() / "*.rules.yml")]
    out.mkdir(parents=True, exist_ok=True)
    (out / "prometheus-kubernetes.promtool.yml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    local = load_yaml_docs(deploy / "prometheus/prometheus.yml")[0]
    local["rule_files"] = cfg["rule_files"]
    (out / "prometheus.promtool.yml").write_text(yaml.safe_dump(local, sort_keys=False))
    return f"{n} kubernetes_sd_configs block(s) checked; promtool copies written with rules resolved locally"


# ------------------------------------------------------------------------------------- compose


def check_compose(deploy: Path, out: Path) -> str:
    compose = load_yaml_docs(deploy / "compose.yaml")[0]
    services = compose["services"]
    expect({"dynaserve", "prometheus", "grafana"} <= set(services), "compose needs dynaserve, prometheus, grafana")
    build = services["dynaserve"]["build"]
    context = (deploy / build["context"]).resolve()
    expect((context / build["dockerfile"]).is_file(), f"compose build: {build} does not find the Dockerfile")
    expect((context / "Cargo.toml").is_file(), "compose build context is not the workspace root")
    mounts = 0
    for name, svc in services.items():
        for vol in svc.get("volumes", []):
            source = vol.split(":")[0]
            if source.startswith("."):
                expect((deploy / source).exists(), f"{name}: bind-mount source {source} does not exist")
                mounts += 1
            else:
                expect(source in compose.get("volumes", {}), f"{name}: named volume {source} not declared")
    container_ports = {int(p.split(":")[-1]) for p in services["dynaserve"]["ports"]}
    expect(container_ports == {HTTP_PORT, GRPC_PORT}, f"dynaserve ports {container_ports}")
    expect(services["dynaserve"]["healthcheck"]["test"][-1] == f"http://127.0.0.1:{HTTP_PORT}/ready",
           "compose healthcheck must poll /ready")
    prom = load_yaml_docs(deploy / "prometheus/prometheus.yml")[0]
    job = next(j for j in prom["scrape_configs"] if j["job_name"] == "dynaserve")
    expect(job["static_configs"][0]["targets"] == [f"dynaserve:{HTTP_PORT}"], "scrape target must be dynaserve:HTTP port")
    ds = load_yaml_docs(deploy / "grafana/provisioning/datasources/prometheus.yaml")[0]["datasources"][0]
    expect(ds["url"] == "http://prometheus:9090", "Grafana datasource must point at the prometheus service")
    grace = parse_duration_s(services["dynaserve"]["stop_grace_period"])
    drain = drain_timeout_s(deploy)
    env = services["dynaserve"]["environment"]
    expect(float(env.get("DYNASERVE_DRAIN_TIMEOUT_S", -1)) == drain, "compose and Kubernetes drain deadlines differ")
    expect(grace > drain + SERVER_CLOSE_GRACE_S,
           f"compose stop_grace_period {grace}s must exceed drain {drain}s + close {SERVER_CLOSE_GRACE_S}s")
    return f"{len(services)} services, {mounts} bind mounts exist, ports and scrape target agree, grace {grace:.0f}s > drain {drain:.0f}s"


# ---------------------------------------------------------------------------------- dockerfile


def check_dockerfile(deploy: Path, out: Path) -> str:
    import dockerfile  # BuildKit's parser, compiled into the python package

    cmds = dockerfile.parse_file(str(deploy / "Dockerfile"))
    stages: list[dict] = []
    for c in cmds:
        if c.cmd == "FROM":
            name = c.value[2] if len(c.value) == 3 and c.value[1].upper() == "AS" else None
            stages.append({"name": name, "base": c.value[0], "cmds": []})
        elif stages:
            stages[-1]["cmds"].append(c)
    expect(len(stages) >= 2, "Dockerfile must be multi-stage")
    names = [s["name"] for s in stages]
    for i, s in enumerate(stages):
        for c in s["cmds"]:
            for flag in c.flags:
                if flag.startswith("--from="):
                    ref = flag.split("=", 1)[1]
                    expect(ref in names[:i], f"COPY --from={ref} refers to no earlier stage")
            if c.cmd == "RUN" and not c.json:
                script = c.value[0]
                res = subprocess.run(["bash", "-n", "-c", script], capture_output=True, text=True)
                expect(res.returncode == 0, f"RUN line {c.start_line} is not valid shell: {res.stderr.strip()}")
    builder = next(s for s in stages if any(c.cmd == "RUN" and "cargo build" in c.value[0] for c in s["cmds"]))
    seq = [(c.cmd, " ".join(c.value)) for c in builder["cmds"]]
    cook = next(i for i, (cmd, v) in enumerate(seq) if cmd == "RUN" and ("cargo chef cook" in v or "cargo build" in v))
    copy_all = next(i for i, (cmd, v) in enumerate(seq) if cmd == "COPY" and v.startswith(". "))
    expect(cook < copy_all and "cargo chef cook" in seq[cook][1],
           "dependencies must be built (cargo chef cook) before the sources are copied")
    rt = stages[-1]["cmds"]
    user = [c.value[0] for c in rt if c.cmd == "USER"]
    expect(user and user[-1].split(":")[0] not in {"0", "root"}, "runtime stage must end as a non-root USER")
    expect(any(c.cmd == "HEALTHCHECK" for c in rt), "runtime stage needs a HEALTHCHECK")
    health = next(c for c in rt if c.cmd == "HEALTHCHECK")
    expect(any(f":{HTTP_PORT}/ready" in v for v in health.value), "HEALTHCHECK must poll /ready on the HTTP port")
    exposed = {int(p.split("/")[0]) for c in rt if c.cmd == "EXPOSE" for p in c.value}
    expect(exposed == {HTTP_PORT, GRPC_PORT}, f"EXPOSE {exposed}")
    expect(any(c.cmd == "COPY" and c.value[0].rstrip("/") == "models" for c in rt), "shipped models must be copied in")
    expect(any(c.cmd == "ENTRYPOINT" for c in rt), "runtime stage needs an ENTRYPOINT")
    expect(not any("protobuf-compiler" in " ".join(c.value) for s in stages for c in s["cmds"]),
           "protoc must come from the protoc-bin-vendored crate, not the system")
    ignore = deploy / "Dockerfile.dockerignore"
    expect(ignore.is_file() and "target" in ignore.read_text(), "Dockerfile.dockerignore must exclude target dirs")
    return f"{len(stages)} stages {names}, cook before sources, USER {user[-1]}, EXPOSE {sorted(exposed)}, all RUN lines parse"


# ----------------------------------------------------------------------------------------- k8s


def drain_timeout_s(deploy: Path) -> float:
    dep = k8s_objects(deploy)[("Deployment", "dynaserve")]
    env = {e["name"]: e.get("value") for e in dep["spec"]["template"]["spec"]["containers"][0].get("env", [])}
    expect("DYNASERVE_DRAIN_TIMEOUT_S" in env, "Deployment must set DYNASERVE_DRAIN_TIMEOUT_S")
    return float(env["DYNASERVE_DRAIN_TIMEOUT_S"])


def k8s_objects(deploy: Path) -> dict[tuple[str, str], dict]:
    objs = {}
    for f in sorted((deploy / "k8s").glob("*.yaml")):
        if f.name == "kustomization.yaml":
            continue
        for d in load_yaml_docs(f):
            objs[(d["kind"], d["metadata"]["name"])] = d
    return objs


def selects(selector: dict, labels: dict) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


def check_k8s(deploy: Path, out: Path) -> str:
    objs = k8s_objects(deploy)
    dep = objs[("Deployment", "dynaserve")]
    pod = dep["spec"]["template"]
    labels = pod["metadata"]["labels"]
    expect(selects(dep["spec"]["selector"]["matchLabels"], labels), "Deployment selector does not match its pods")
    c = pod["spec"]["containers"][0]
    ports = {p["name"]: p["containerPort"] for p in c["ports"]}
    expect(ports == {"http": HTTP_PORT, "grpc": GRPC_PORT}, f"container ports {ports}")
    # In this server the gRPC health status and /ready both mean "warmed up and not draining";
    # /health means "the process serves HTTP". So readiness uses either of the former and
    # liveness must use /health (a draining server must not be restarted).
    rp = c["readinessProbe"]
    expect(rp.get("grpc", {}).get("port") == GRPC_PORT or rp.get("httpGet", {}).get("path") == "/ready",
           "readiness must use the gRPC health service or GET /ready")
    lp = c["livenessProbe"]
    expect(lp.get("httpGet", {}).get("path") == "/health", "liveness must use GET /health")
    expect(c.get("startupProbe", {}).get("httpGet", {}).get("path") == "/health",
           "a startup probe on /health must cover model loading (listeners bind after it)")
    req = c["resources"]["requests"]
    expect("memory" in req and "cpu" in req, "resource requests must set memory and cpu")
    expect("memory" in c["resources"].get("limits", {}), "a memory limit must be set")
    pre = c["lifecycle"]["preStop"]["exec"]["command"]
    pre_s = float(pre[1]) if pre[0] == "sleep" else 0.0
    drain = drain_timeout_s(deploy)
    grace = pod["spec"]["terminationGracePeriodSeconds"]
    expect(grace > pre_s + drain + SERVER_CLOSE_GRACE_S,
           f"terminationGracePeriodSeconds {grace} must exceed preStop {pre_s}s + drain {drain}s + close {SERVER_CLOSE_GRACE_S}s")
    expect(pod["metadata"]["annotations"]["prometheus.io/port"] == str(HTTP_PORT), "scrape annotation port")

    servers = [o for (k, _), o in objs.items() if k == "Service" and selects(o["spec"]["selector"], labels)]
    expect(servers, "no Service selects the server pods")
    headless = [s for s in servers if s["spec"].get("clusterIP") == "None"]
    expect(len(headless) == 1, "exactly one headless Service must select the server pods")
    for s in servers:
        for p in s["spec"]["ports"]:
            expect(p["targetPort"] in ports, f"Service {s['metadata']['name']}: unknown targetPort {p['targetPort']}")

    pdbs = [o for (k, _), o in objs.items() if k == "PodDisruptionBudget" and selects(o["spec"]["selector"]["matchLabels"], labels)]
    expect(len(pdbs) == 1, "exactly one PodDisruptionBudget must cover the server pods")

    hpa = objs[("HorizontalPodAutoscaler", "dynaserve")]
    ref = hpa["spec"]["scaleTargetRef"]
    expect((ref["kind"], ref["name"]) == ("Deployment", "dynaserve"), "HPA must target the Deployment")
    kinds = {m["type"] for m in hpa["spec"]["metrics"]}
    expect({"Pods", "Resource"} <= kinds, "HPA needs a serving (Pods) metric and the CPU fallback")
    values = load_yaml_docs(deploy / "k8s/prometheus-adapter/values.yaml")[0]
    served = {r["name"]["as"] for r in values["rules"]["custom"]}
    for m in hpa["spec"]["metrics"]:
        if m["type"] == "Pods":
            expect(m["pods"]["metric"]["name"] in served,
                   f"HPA metric {m['pods']['metric']['name']} is not served by the adapter rules {served}")

    # Envoy: routes point at defined clusters; clusters resolve the headless Service's ports.
    envoy = yaml.safe_load(objs[("ConfigMap", "dynaserve-gateway")]["data"]["envoy.yaml"])
    clusters = {cl["name"]: cl for cl in envoy["static_resources"]["clusters"]}
    hs = headless[0]
    hs_ports = {p["port"] for p in hs["spec"]["ports"]}
    listener_ports = set()
    for lst in envoy["static_resources"]["listeners"]:
        listener_ports.add(lst["address"]["socket_address"]["port_value"])
        for fc in lst["filter_chains"]:
            for flt in fc["filters"]:
                hcm = flt["typed_config"]
                expect(hcm["http_filters"][-1]["name"] == "envoy.filters.http.router", "router must be the last filter")
                for vh in hcm["route_config"]["virtual_hosts"]:
                    for r in vh["routes"]:
                        expect(r["route"]["cluster"] in clusters, f"route to unknown cluster {r['route']['cluster']}")
    for cl in clusters.values():
        expect(cl["type"] in {"STRICT_DNS", "LOGICAL_DNS", "EDS"}, f"cluster {cl['name']}: type")
        expect(cl.get("health_checks"), f"cluster {cl['name']}: needs active health checks")
        for ep in cl["load_assignment"]["endpoints"]:
            for lb in ep["lb_endpoints"]:
                sa = lb["endpoint"]["address"]["socket_address"]
                expect(sa["address"].split(".")[0] == hs["metadata"]["name"],
                       f"cluster {cl['name']} must resolve the headless Service, not {sa['address']}")
                expect(sa["port_value"] in hs_ports, f"cluster {cl['name']}: port {sa['port_value']} not on the headless Service")
    expect("http2_protocol_options" in json.dumps(clusters["dynaserve_grpc"]), "gRPC upstream must speak HTTP/2")
    # Session affinity: on both listeners, a request with the affinity header is routed first,
    # by consistent hashing of that header, to a hashing cluster of the same pods and port.
    affinity = 0
    for lst in envoy["static_resources"]["listeners"]:
        port = lst["address"]["socket_address"]["port_value"]
        routes = [r for fc in lst["filter_chains"] for flt in fc["filters"]
                  for vh in flt["typed_config"]["route_config"]["virtual_hosts"] for r in vh["routes"]]
        first = routes[0]
        headers = [h["name"] for h in first["match"].get("headers", []) if h.get("present_match")]
        expect(headers == [AFFINITY_HEADER], f"listener {port}: the first route must match on {AFFINITY_HEADER}")
        hashed = [h["header"]["header_name"] for h in first["route"].get("hash_policy", []) if "header" in h]
        expect(hashed == [AFFINITY_HEADER], f"listener {port}: the affinity route must hash {AFFINITY_HEADER}")
        target = clusters[first["route"]["cluster"]]
        expect(target["lb_policy"] in {"RING_HASH", "MAGLEV"},
               f"listener {port}: affinity cluster {target['name']} must balance by consistent hashing")
        plain = clusters[routes[-1]["route"]["cluster"]]
        ports = lambda cl: {lb["endpoint"]["address"]["socket_address"]["port_value"]
                            for ep in cl["load_assignment"]["endpoints"] for lb in ep["lb_endpoints"]}
        expect(ports(target) == ports(plain), f"listener {port}: affinity and plain clusters must reach the same port")
        expect(target.get("typed_extension_protocol_options") == plain.get("typed_extension_protocol_options"),
               f"listener {port}: affinity cluster must speak the plain cluster's protocol")
        affinity += 1
    gw = objs[("Deployment", "dynaserve-gateway")]
    gw_ports = {p["containerPort"] for p in gw["spec"]["template"]["spec"]["containers"][0]["ports"]}
    expect(gw_ports == listener_ports, f"gateway container ports {gw_ports} != Envoy listeners {listener_ports}")

    kust = load_yaml_docs(deploy / "k8s/kustomization.yaml")[0]
    files = {f.name for f in (deploy / "k8s").glob("*.yaml")} - {"kustomization.yaml"}
    expect(set(kust["resources"]) == files, f"kustomization resources {kust['resources']} != files {sorted(files)}")
    return (f"{len(objs)} objects; probes ok; grace {grace}s > preStop {pre_s:.0f}s + drain {drain:.0f}s + close {SERVER_CLOSE_GRACE_S:.0f}s; "
            f"HPA metrics {sorted(kinds)}; Envoy {len(clusters)} clusters -> {hs['metadata']['name']}, "
            f"session affinity on {affinity} listeners")


def check_envoy(deploy: Path, out: Path) -> str:
    """Parse the gateway's Envoy bootstrap into Envoy's own API types (v3 protos, as Python
    classes from the `envoy-data-plane` package): unknown fields, bad enums, durations and
    types inside typed_config (Any) are rejected as Envoy would reject them."""
    import importlib

    from envoy_data_plane.envoy.config.bootstrap.v3 import Bootstrap

    cm = k8s_objects(deploy)[("ConfigMap", "dynaserve-gateway")]
    cfg = yaml.safe_load(cm["data"]["envoy.yaml"])
    # Register every extension type named by an "@type" so that Any fields can be unpacked.
    types = set(re.findall(r'"@type": "?type\.googleapis\.com/([\w.]+)', json.dumps(cfg)))
    for t in types:
        module, _, _ = t.rpartition(".")
        importlib.import_module("envoy_data_plane." + module)
    boot = Bootstrap.from_dict(cfg)
    sr = boot.static_resources
    return f"Envoy v3 Bootstrap parsed: {len(sr.listeners)} listeners, {len(sr.clusters)} clusters, {len(types)} typed extensions"


# --------------------------------------------------------------------------------------- names


def metric_names(deploy: Path) -> set[str]:
    """Every server metric (dynaserve_*) read by the dashboard, the alert rules and the adapter."""
    names: set[str] = set()
    for rel in ("grafana/dashboards/dynaserve.json", "prometheus/rules/dynaserve.rules.yml"):
        names |= set(METRIC_RE.findall((deploy / rel).read_text()))
    # The adapter reads server series (seriesQuery) and publishes them under its own names.
    values = load_yaml_docs(deploy / "k8s/prometheus-adapter/values.yaml")[0]
    for rule in values["rules"]["custom"]:
        names |= set(METRIC_RE.findall(rule["seriesQuery"]))
    return names


def check_names(deploy: Path, out: Path) -> str:
    names = sorted(metric_names(deploy))
    (out / "metric-names.txt").write_text("\n".join(names) + "\n")
    return "metric names used: " + " ".join(names)


CHECKS = {
    "dashboard": check_dashboard,
    "promql": check_promql,
    "prometheus-k8s": check_prometheus_k8s,
    "compose": check_compose,
    "dockerfile": check_dockerfile,
    "k8s": check_k8s,
    "envoy": check_envoy,
    "names": check_names,
}


def main(argv: list[str]) -> int:
    if len(argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    deploy, out = Path(argv[1]), Path(argv[2])
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for name in argv[3:]:
        try:
            detail = CHECKS[name](deploy, out)
            print(f"ok   {name}: {detail}")
        except (CheckError, KeyError, StopIteration, TypeError, ValueError, AttributeError, IndexError,
                ImportError) as e:
            failed += 1
            print(f"FAIL {name}: {type(e).__name__}: {e}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
