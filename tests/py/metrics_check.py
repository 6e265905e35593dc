"""Scrape skyfuse's /metrics as Prometheus would and check it against /api/v1/status.

The text is parsed by the Prometheus project's own Python client (its strict
OpenMetrics parser: a malformed line, a missing `# EOF`, a counter without `_total`
fail it). Two scrapes one second apart: counters never go back, samples keep flowing.
Prints a JSON summary; exits non-zero, saying what disagreed, on any mismatch.
"""

import argparse
import json
import sys
import time
import urllib.request

from prometheus_client.openmetrics.parser import text_string_to_metric_families


def get(port, path):
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
        return r.headers.get("Content-Type", ""), r.read().decode()


def scrape(port):
    ctype, text = get(port, "/metrics")
    if not ctype.startswith("application/openmetrics-text"):
        sys.exit(f"/metrics content type {ctype!r}")
    samples = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return samples


def one(samples, name, **labels):
    key = (name, tuple(sorted(labels.items())))
    if key not in samples:
        sys.exit(f"no sample {name}{labels}")
    return samples[key]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    args = ap.parse_args()
    first = scrape(args.port)
    _, body = get(args.port, "/api/v1/status")
    status = json.loads(body)
    problems = []
    ids = sorted(s["id"] for s in status["sensors"])
    in_metrics = sorted({dict(k[1])["input"] for k in first if k[0] == "skyfuse_input_received_total"})
    if ids != in_metrics:
        problems.append(f"inputs: status {ids}, metrics {in_metrics}")
    for s in status["sensors"]:
        sid = s["id"]
        states = {dict(k[1])["state"]: v for k, v in first.items()
                  if k[0] == "skyfuse_sensor_health" and dict(k[1])["input"] == sid}
        current = [st for st, v in states.items() if v == 1.0]
        if len(states) != 6 or len(current) != 1:
            problems.append(f"{sid}: health states {states}")
        elif current[0] != s["health"]:
            # Read from the same typed status a moment apart: on the steady demo no
            # sensor changes state in between.
            problems.append(f"{sid}: health {current[0]} in metrics, {s['health']} in status")
        got = one(first, "skyfuse_input_received_total", input=sid, kind=s["kind"])
        # Scraped first: never more than the status read after it, and not far behind.
        if got > s["received"] or s["received"] - got > 2 * max(s["expected_rate_hz"], 1) + 50:
            problems.append(f"{sid}: received {got} in metrics, {s['received']} in status")
    valid = one(first, "skyfuse_estimate_valid")
    if (valid == 1.0) != status["estimator"]["valid"]:
        problems.append(f"estimate_valid {valid}, status valid {status['estimator']['valid']}")
    refused = one(first, "skyfuse_controls_refused_total")
    if refused != status["controls"]["refused"]:
        problems.append(f"controls_refused {refused} vs {status['controls']['refused']}")
    rec = status.get("recorder")
    if rec:
        # The demo serves Foxglove; the recorder's counters follow the status.
        logged = one(first, "skyfuse_recorder_messages_total")
        if logged > rec["messages"] or logged == 0:
            problems.append(f"recorder messages {logged} in metrics, {rec['messages']} in status")
        if one(first, "skyfuse_recorder_dropped_total") != rec["dropped"]:
            problems.append(f"recorder dropped vs {rec['dropped']}")
    std = [one(first, "skyfuse_estimate_position_std_meters", axis=a) for a in "xyz"]
    if any(abs(m - s) > 0.5 for m, s in zip(std, status["estimator"]["position_std"])):
        problems.append(f"position std {std} vs {status['estimator']['position_std']}")
    time.sleep(1.0)
    second = scrape(args.port)
    went_back = [k for k, v in first.items()
                 if k[0].endswith("_total") and second.get(k, -1) < v]
    if went_back:
        problems.append(f"counters went back: {went_back}")
    sent = [second[k] - first[k] for k in first if k[0] == "skyfuse_output_sent_total"]
    if not sent or min(sent) <= 0:
        problems.append(f"outputs sent nothing in 1 s: {sent}")
    if one(second, "skyfuse_uptime_seconds") <= one(first, "skyfuse_uptime_seconds"):
        problems.append("uptime did not advance")
    summary = {
        "samples": len(first),
        "families": len({k[0] for k in first}),
        "inputs": len(ids),
        "vpe_per_s": second.get(("skyfuse_output_sent_total", (("kind", "mavlink"), ("output", "mavlink"))), 0)
        - first.get(("skyfuse_output_sent_total", (("kind", "mavlink"), ("output", "mavlink"))), 0),
        "rss_mb": round(second.get(("process_resident_memory_bytes", ()), 0) / 2**20, 1),
        "cpu_s": second.get(("process_cpu_seconds_total", ()), None),
        "problems": problems,
    }
    print(json.dumps(summary))
    if problems:
        sys.exit("\n".join(problems))


if __name__ == "__main__":
    main()
