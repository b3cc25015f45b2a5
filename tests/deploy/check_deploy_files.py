#!/usr/bin/env python3
"""Checks the deployment files against the repository and this build's esgd.

    python3 tests/deploy/check_deploy_files.py PATH/TO/esgd [--root REPO]

Nothing is built, pulled or started except `esgd --help`. Checked (docs/deploy.md
"Containers"):
  - deploy/compose.yaml and every deploy/k8s/*.yaml parse as YAML;
  - every esgd flag they and the Dockerfile use is one `esgd --help` lists; every console flag
    is one the gateway's usage text (console/gateway/cli.js) lists;
  - ports agree: esgd --listen and --metrics-listen vs the Dockerfile's EXPOSE, the containers'
    ports, the probes, the Services' targetPort and nginx's upstream servers; nginx's listen vs
    the router's container port and Service and the console's --esgd; the console's --listen vs
    its container port and Service;
  - the gRPC probes name a service esgd's health service serves (server/server.cc);
  - every file the Dockerfile COPYs or RUNs exists in the repository, every stage compose builds
    exists, and the binaries the runtime stage copies are esgd's and esg's CMake targets;
  - the compose and Kubernetes nginx configurations keep the directives of deploy/nginx/esg.conf.
Prints one line per failed check and exits 1 if any failed.
"""
import argparse
import glob
import os
import re
import subprocess
import sys

import yaml

failures = []


def fail(where, message):
    failures.append(f"{where}: {message}")


def host_port(value):
    m = re.fullmatch(r"\[?([^\]]*?)\]?:(\d+)", value)
    return (m.group(1), int(m.group(2))) if m else (None, None)


def flags_of(args):
    """{flag: value or None} of an argument list (--flag value, --flag=value)."""
    out = {}
    i = 0
    while i < len(args):
        a = str(args[i])
        if a.startswith("--"):
            if "=" in a:
                name, value = a.split("=", 1)
            elif i + 1 < len(args) and not str(args[i + 1]).startswith("--"):
                name, value = a, str(args[i + 1])
                i += 1
            else:
                name, value = a, None
            out[name] = value
        i += 1
    return out


def check_flags(where, args, known, program):
    for name in flags_of(args):
        if name not in known:
            fail(where, f"{program} has no flag {name}")


# ---------------------------------------------------------------------------------------------
# What the repository says.

def esgd_flags(esgd):
    text = subprocess.run([esgd, "--help"], capture_output=True, text=True, check=True).stdout
    return set(re.findall(r"(--[a-z][a-z0-9-]*)", text))


def console_flags(root):
    src = open(os.path.join(root, "console/gateway/cli.js")).read()
    usage = re.search(r"const USAGE = `(.*?)`;", src, re.S)
    if not usage:
        fail("console/gateway/cli.js", "no USAGE text found")
        return set()
    return set(re.findall(r"(--[a-z][a-z0-9-]*)", usage.group(1)))


def health_services(root):
    src = open(os.path.join(root, "server/server.cc")).read()
    return set(re.findall(r'SetServingStatus\("([^"]*)"', src))


def dockerfile_stages(root):
    """{stage: {'from': image, 'instructions': [(keyword, text)]}} of the Dockerfile."""
    lines = open(os.path.join(root, "deploy/container/Dockerfile")).read().split("\n")
    logical, cur = [], ""
    for line in lines:
        if not cur and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.lstrip().startswith("#"):
            continue
        if line.rstrip().endswith("\\"):
            cur += line.rstrip()[:-1] + " "
        else:
            logical.append(cur + line)
            cur = ""
    stages, stage = {}, None
    for instr in logical:
        keyword, _, rest = instr.strip().partition(" ")
        keyword = keyword.upper()
        if keyword == "FROM":
            m = re.fullmatch(r"(\S+)(?:\s+AS\s+(\S+))?", rest.strip(), re.I)
            stage = m.group(2) or m.group(1)
            stages[stage] = {"from": m.group(1), "instructions": []}
        elif stage:
            stages[stage]["instructions"].append((keyword, rest.strip()))
    return stages


def exec_form(text):
    m = re.fullmatch(r"\[(.*)\]", text.strip())
    return re.findall(r'"([^"]*)"', m.group(1)) if m else text.split()


def cmake_target_dir(root, target):
    """The source directory whose CMakeLists.txt adds the executable `target`."""
    for path in glob.glob(os.path.join(root, "**/CMakeLists.txt"), recursive=True):
        if "/build" in os.path.relpath(path, root) or "node_modules" in path:
            continue
        if re.search(r"add_executable\(\s*" + re.escape(target) + r"\b", open(path).read()):
            return os.path.relpath(os.path.dirname(path), root)
    return None


def nginx_directives(text):
    """(directives outside upstream servers and listen, upstream servers, listen ports) of the
    first upstream and server blocks of an nginx configuration."""
    lines = [re.sub(r"#.*", "", l).strip() for l in text.split("\n")]
    lines = [re.sub(r"\s+", " ", l) for l in lines if l]
    directives, servers, listens = [], [], []
    in_upstream = False
    for l in lines:
        if l.startswith("upstream "):
            in_upstream = True
        elif l == "}" and in_upstream:
            in_upstream = False
        m = re.fullmatch(r"server (\S+:\d+)( .*)?;", l)
        if in_upstream and m:
            servers.append(m.group(1))
            directives.append("server ADDRESS" + (m.group(2) or ""))
            continue
        m = re.fullmatch(r"listen (\d+)( .*)?;", l)
        if m:
            listens.append(int(m.group(1)))
            directives.append("listen PORT" + (m.group(2) or ""))
            continue
        directives.append(l)
    return directives, servers, listens


# ---------------------------------------------------------------------------------------------

def check_dockerfile(root, stages):
    where = "deploy/container/Dockerfile"
    for name in ("build", "esgd", "console", "router"):
        if name not in stages:
            fail(where, f"no stage {name}")
    for name, stage in stages.items():
        if not stage["from"].startswith(("debian:12", "node:20-bookworm")) and stage["from"] not in stages:
            fail(where, f"stage {name}: FROM {stage['from']} is not Debian 12")
        for keyword, text in stage["instructions"]:
            if keyword in ("COPY", "ADD"):
                parts = text.split()
                if any(p.startswith("--from=") for p in parts):
                    sources = [p for p in parts if not p.startswith("--")][:-1]
                    src_stage = [p for p in parts if p.startswith("--from=")][0][7:]
                    if src_stage not in stages:
                        fail(where, f"COPY --from={src_stage}: no such stage")
                    for s in sources:
                        m = re.fullmatch(r"/opt/esg/bin/(\w+)", s)
                        if m and cmake_target_dir(root, m.group(1)) is None:
                            fail(where, f"COPY {s}: no CMake executable {m.group(1)}")
                    continue
                for s in [p for p in parts if not p.startswith("--")][:-1]:
                    if not os.path.exists(os.path.join(root, s)):
                        fail(where, f"COPY {s}: not in the repository")
            if keyword == "RUN":
                for token in re.findall(r"(?<![\w/.-])((?:scripts|deploy|console|proto|server|client)/[\w./-]+)", text):
                    if not os.path.exists(os.path.join(root, token)):
                        fail(where, f"RUN uses {token}: not in the repository")
                words = text.split()
                for i, w in enumerate(words):
                    if w != "--target":
                        continue
                    for t in words[i + 1:]:
                        if t.startswith(("-", "&", "|", ";")):
                            break
                        if cmake_target_dir(root, t) is None:
                            fail(where, f"RUN builds target {t}: no CMake executable of that name")
    users = [t for k, t in stages.get("esgd", {"instructions": []})["instructions"] if k == "USER"]
    if not users or users[-1] in ("root", "0"):
        fail(where, "stage esgd does not run as a non-root USER")


def exposed(stages, stage):
    ports = set()
    for k, t in stages.get(stage, {"instructions": []})["instructions"]:
        if k == "EXPOSE":
            ports |= {int(p.split("/")[0]) for p in t.split()}
    return ports


def entry_args(stages, stage, keyword):
    for k, t in reversed(stages.get(stage, {"instructions": []})["instructions"]):
        if k == keyword:
            return exec_form(t)
    return []


def check_esgd_args(where, args, known_esgd, stages):
    """The flags and ports of one esgd command line; returns (listen port, metrics port)."""
    check_flags(where, args, known_esgd, "esgd")
    f = flags_of(args)
    listen_host, listen = host_port(f.get("--listen") or "")
    metrics_host, metrics = host_port(f.get("--metrics-listen") or "")
    if listen is None:
        fail(where, "esgd without --listen HOST:PORT (the default is 127.0.0.1, unreachable)")
    elif listen_host in ("127.0.0.1", "localhost", "::1"):
        fail(where, f"esgd --listen {f['--listen']} is loopback: unreachable from outside")
    if metrics is None:
        fail(where, "esgd without --metrics-listen HOST:PORT")
    for port, flag in ((listen, "--listen"), (metrics, "--metrics-listen")):
        if port is not None and port not in exposed(stages, "esgd"):
            fail(where, f"esgd {flag} port {port} is not EXPOSEd by the Dockerfile's esgd stage")
    return listen, metrics


def check_compose(root, stages, known_esgd, known_console, health):
    where = "deploy/compose.yaml"
    try:
        doc = yaml.safe_load(open(os.path.join(root, where)))
    except yaml.YAMLError as e:
        fail(where, f"not valid YAML: {e}")
        return
    services = doc.get("services", {})
    esgd = {n: s for n, s in services.items() if s.get("build", {}).get("target") == "esgd"}
    if len(esgd) < 2:
        fail(where, f"{len(esgd)} esgd services, expected several")
    for name, s in services.items():
        build = s.get("build")
        if build:
            dockerfile = os.path.normpath(os.path.join(root, "deploy", build.get("context", "."),
                                                       build.get("dockerfile", "Dockerfile")))
            if not os.path.exists(dockerfile):
                fail(where, f"{name}: build dockerfile {dockerfile} does not exist")
            if build.get("target") not in stages:
                fail(where, f"{name}: build target {build.get('target')} is no Dockerfile stage")
        for v in s.get("volumes", []):
            src = v.split(":")[0]
            if src.startswith("."):
                if not os.path.exists(os.path.join(root, "deploy", src)):
                    fail(where, f"{name}: volume {src} does not exist")

    node_ids, listens = {}, {}
    pg = [n for n, s in services.items() if str(s.get("image", "")).startswith("postgres")]
    for name, s in esgd.items():
        args = s.get("command", [])
        listen, metrics = check_esgd_args(f"{where} {name}", args, known_esgd, stages)
        listens[name] = listen
        f = flags_of(args)
        node = f.get("--node-id")
        if not node:
            fail(where, f"{name}: no --node-id")
        elif node in node_ids:
            fail(where, f"{name}: --node-id {node} is also {node_ids[node]}'s")
        node_ids[node] = name
        db = f.get("--db") or ""
        m = re.fullmatch(r"postgres(?:ql)?://[^@/]+@([^:/]+):(\d+)/\w+", db)
        if not m:
            fail(where, f"{name}: --db {db!r} is not postgresql://user@host:port/db")
        elif m.group(1) not in pg or int(m.group(2)) != 5432:
            fail(where, f"{name}: --db host {m.group(1)}:{m.group(2)} is not the postgres "
                        f"service ({', '.join(pg) or 'none'}) on 5432")
        published = [str(p).rsplit(":", 1)[-1] for p in s.get("ports", [])]
        for p in published:
            if int(p) not in (listen, metrics):
                fail(where, f"{name}: publishes container port {p}, which esgd does not serve")

    routers = {n: s for n, s in services.items() if s.get("build", {}).get("target") == "router"}
    router_ports = {}
    for name, s in routers.items():
        conf = None
        for v in s.get("volumes", []):
            src, dst = v.split(":")[:2]
            if dst.startswith("/etc/nginx/"):
                conf = os.path.join(root, "deploy", src)
        if conf is None or not os.path.exists(conf):
            fail(where, f"{name}: no nginx configuration mounted")
            continue
        _, servers, nginx_listens = check_nginx(os.path.relpath(conf, root), open(conf).read(), root)
        router_ports[name] = nginx_listens
        wanted = {f"{n}:{p}" for n, p in listens.items()}
        if set(servers) != wanted:
            fail(os.path.relpath(conf, root), f"upstream servers {sorted(servers)} are not the "
                                              f"esgd services at their --listen port {sorted(wanted)}")
        for p in nginx_listens:
            if p not in exposed(stages, "router"):
                fail(where, f"{name}: nginx listens on {p}, not EXPOSEd by the router stage")
        for p in s.get("ports", []):
            if int(str(p).rsplit(":", 1)[-1]) not in nginx_listens:
                fail(where, f"{name}: publishes container port {p}, nginx listens on {nginx_listens}")
    if not routers:
        fail(where, "no router (nginx) service")

    consoles = {n: s for n, s in services.items() if s.get("build", {}).get("target") == "console"}
    for name, s in consoles.items():
        args = s.get("command", [])
        check_flags(f"{where} {name}", args, known_console, "the console gateway")
        f = flags_of(args)
        host, port = host_port(f.get("--esgd") or "")
        if host not in router_ports or port not in router_ports.get(host, []):
            fail(where, f"{name}: --esgd {f.get('--esgd')} is not a router service at its nginx port")
        lhost, lport = host_port(f.get("--listen") or "")
        if lhost in (None, "127.0.0.1", "localhost"):
            fail(where, f"{name}: --listen {f.get('--listen')} is not reachable from outside")
        if lport not in exposed(stages, "console"):
            fail(where, f"{name}: --listen port {lport} not EXPOSEd by the console stage")
        for p in s.get("ports", []):
            if int(str(p).rsplit(":", 1)[-1]) != lport:
                fail(where, f"{name}: publishes container port {p}, the console listens on {lport}")
    if not consoles:
        fail(where, "no console service")


def check_nginx(where, text, root):
    reference, _, _ = nginx_directives(open(os.path.join(root, "deploy/nginx/esg.conf")).read())
    directives, servers, listens = nginx_directives(text)
    base = [d for d in reference if d != "server ADDRESS max_fails=1 fail_timeout=10s;"]
    mine = [d for d in directives if d != "server ADDRESS max_fails=1 fail_timeout=10s;"]
    if base != mine:
        missing = [d for d in base if d not in mine]
        extra = [d for d in mine if d not in base]
        fail(where, f"directives differ from deploy/nginx/esg.conf: missing {missing}, extra {extra}")
    return directives, servers, listens


def container_port(container, ref):
    """A container port by number or name."""
    for p in container.get("ports", []):
        if ref == p.get("containerPort") or ref == p.get("name"):
            return p.get("containerPort")
    return None


def check_k8s(root, stages, known_esgd, known_console, health):
    docs = []
    for path in sorted(glob.glob(os.path.join(root, "deploy/k8s/*.yaml"))):
        rel = os.path.relpath(path, root)
        try:
            docs += [(rel, d) for d in yaml.safe_load_all(open(path)) if d]
        except yaml.YAMLError as e:
            fail(rel, f"not valid YAML: {e}")
    if not docs:
        fail("deploy/k8s", "no manifests")
        return
    by_kind = {}
    for rel, d in docs:
        by_kind.setdefault(d.get("kind"), []).append((rel, d))
    secrets = {d["metadata"]["name"]: d for _, d in by_kind.get("Secret", [])}
    services = by_kind.get("Service", [])

    def services_of(labels):
        return [(rel, s) for rel, s in services
                if s["spec"].get("selector") and
                all(labels.get(k) == v for k, v in s["spec"]["selector"].items())]

    stateful = by_kind.get("StatefulSet", [])
    if not stateful:
        fail("deploy/k8s", "no StatefulSet (esgd)")
    pods = {}  # "host:port" -> what serves there
    for rel, sts in stateful:
        spec = sts["spec"]
        name, ns = sts["metadata"]["name"], sts["metadata"].get("namespace", "default")
        labels = spec["template"]["metadata"]["labels"]
        headless = [s for _, s in services if s["metadata"]["name"] == spec.get("serviceName")]
        if not headless or headless[0]["spec"].get("clusterIP") != "None":
            fail(rel, f"StatefulSet {name}: serviceName {spec.get('serviceName')} is no headless Service")
        for c in spec["template"]["spec"]["containers"]:
            where = f"{rel} {name}/{c['name']}"
            args = list(c.get("command", [])[1:]) + list(c.get("args", []))
            listen, metrics = check_esgd_args(where, args, known_esgd, stages)
            f = flags_of(args)
            env = {e["name"]: e for e in c.get("env", [])}
            node = f.get("--node-id") or ""
            m = re.fullmatch(r"\$\((\w+)\)", node)
            if not m or env.get(m.group(1), {}).get("valueFrom", {}).get("fieldRef", {}).get(
                    "fieldPath") != "metadata.name":
                fail(where, f"--node-id {node!r} is not the pod name (downward API metadata.name)")
            db = f.get("--db") or ""
            m = re.fullmatch(r"\$\((\w+)\)", db)
            ref = env.get(m.group(1), {}).get("valueFrom", {}).get("secretKeyRef") if m else None
            if not ref:
                fail(where, f"--db {db!r} is not taken from a Secret")
            for e in env.values():
                r = e.get("valueFrom", {}).get("secretKeyRef")
                if r and r["name"] in secrets and r["key"] not in secrets[r["name"]].get("stringData", {}):
                    fail(where, f"env {e['name']}: Secret {r['name']} has no key {r['key']}")
            for flag, port in (("--listen", listen), ("--metrics-listen", metrics)):
                if port is not None and container_port(c, port) is None:
                    fail(where, f"esgd {flag} port {port} is not a containerPort")
            for probe in ("readinessProbe", "livenessProbe"):
                p = c.get(probe)
                if not p or "grpc" not in p:
                    fail(where, f"no gRPC {probe}")
                    continue
                if p["grpc"].get("port") != listen:
                    fail(where, f"{probe} port {p['grpc'].get('port')} is not --listen's {listen}")
                service = p["grpc"].get("service", "")
                if service not in health:
                    fail(where, f"{probe} service {service!r} is not served by esgd's health "
                                f"service ({sorted(health)})")
            for srel, s in services_of(labels):
                for sp in s["spec"]["ports"]:
                    if container_port(c, sp.get("targetPort", sp["port"])) is None:
                        fail(srel, f"Service {s['metadata']['name']} targetPort "
                                   f"{sp.get('targetPort')} is no port of {name}")
            svc = spec.get("serviceName")
            for i in range(spec.get("replicas", 1)):
                pods[f"{name}-{i}.{svc}.{ns}.svc.cluster.local:{listen}"] = name

    router_addresses = {}
    for rel, cm in by_kind.get("ConfigMap", []):
        for key, text in cm.get("data", {}).items():
            if "upstream" not in text:
                continue
            where = f"{rel} ConfigMap {cm['metadata']['name']} {key}"
            _, servers, listens = check_nginx(where, text, root)
            if set(servers) != set(pods):
                fail(where, f"upstream servers {sorted(servers)} are not the esgd pods at their "
                            f"--listen port {sorted(pods)}")
            # The Deployment mounting it, and the Services in front of that.
            for drel, dep in by_kind.get("Deployment", []):
                pod = dep["spec"]["template"]
                vols = [v for v in pod["spec"].get("volumes", [])
                        if v.get("configMap", {}).get("name") == cm["metadata"]["name"]]
                if not vols:
                    continue
                for c in pod["spec"]["containers"]:
                    for p in listens:
                        if container_port(c, p) is None:
                            fail(drel, f"{dep['metadata']['name']}: nginx listens on {p}, not a containerPort")
                        if p not in exposed(stages, "router"):
                            fail(drel, f"nginx listens on {p}, not EXPOSEd by the router stage")
                    for srel, s in services_of(pod["metadata"]["labels"]):
                        ns = s["metadata"].get("namespace", "default")
                        for sp in s["spec"]["ports"]:
                            target = container_port(c, sp.get("targetPort", sp["port"]))
                            if target not in listens:
                                fail(srel, f"Service {s['metadata']['name']} targetPort "
                                           f"{sp.get('targetPort')} is not nginx's {listens}")
                            router_addresses[f"{s['metadata']['name']}.{ns}.svc.cluster.local:{sp['port']}"] = 1
    if not router_addresses:
        fail("deploy/k8s", "no router: no Deployment mounting an nginx ConfigMap behind a Service")

    for drel, dep in by_kind.get("Deployment", []):
        pod = dep["spec"]["template"]
        for c in pod["spec"]["containers"]:
            if "console" not in c.get("image", ""):
                continue
            where = f"{drel} {dep['metadata']['name']}/{c['name']}"
            args = list(c.get("args", []))
            check_flags(where, args, known_console, "the console gateway")
            f = flags_of(args)
            if f.get("--esgd") not in router_addresses:
                fail(where, f"--esgd {f.get('--esgd')} is not the router Service ({sorted(router_addresses)})")
            _, lport = host_port(f.get("--listen") or "")
            if container_port(c, lport) is None:
                fail(where, f"--listen port {lport} is not a containerPort")
            if lport not in exposed(stages, "console"):
                fail(where, f"--listen port {lport} not EXPOSEd by the console stage")
            for srel, s in services_of(pod["metadata"]["labels"]):
                for sp in s["spec"]["ports"]:
                    if container_port(c, sp.get("targetPort", sp["port"])) != lport:
                        fail(srel, f"Service {s['metadata']['name']} targetPort "
                                   f"{sp.get('targetPort')} is not the console's {lport}")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("esgd", help="the esgd binary whose --help gives the flags")
    parser.add_argument("--root", default=os.path.join(os.path.dirname(__file__), "..", ".."))
    a = parser.parse_args()
    root = os.path.abspath(a.root)
    known_esgd = esgd_flags(a.esgd)
    known_console = console_flags(root)
    health = health_services(root)
    if not known_esgd or not known_console or not health:
        fail("setup", f"esgd flags {len(known_esgd)}, console flags {len(known_console)}, "
                      f"health services {sorted(health)}")
    stages = dockerfile_stages(root)
    check_dockerfile(root, stages)
    check_esgd_args("deploy/container/Dockerfile esgd CMD",
                    entry_args(stages, "esgd", "CMD"), known_esgd, stages)
    check_compose(root, stages, known_esgd, known_console, health)
    check_k8s(root, stages, known_esgd, known_console, health)
    for f in failures:
        print("FAIL", f)
    print(f"deploy files: {len(failures)} failed check(s)" if failures else "deploy files: all checks passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
