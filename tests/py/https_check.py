#!/usr/bin/env python3
"""The dashboard over HTTPS, checked with Python's own TLS (ssl, certificate verified
against the test's CA): the page, the token page and the API answer over TLS; plain
HTTP to the same port gets no HTTP answer; a client that does not trust the
certificate is refused by its own verification. Prints JSON.

  https_check.py --port 8443 --ca cert.pem
"""
import argparse
import http.client
import json
import ssl
import time


def get(port, path, ctx):
    c = http.client.HTTPSConnection("127.0.0.1", port, context=ctx, timeout=5)
    c.request("GET", path)
    r = c.getresponse()
    return r.status, r.read().decode("utf-8", "replace")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--ca", required=True)
    a = ap.parse_args()
    ctx = ssl.create_default_context(cafile=a.ca)
    report = {}
    deadline = time.time() + 30
    while True:
        try:
            status, _ = get(a.port, "/healthz", ctx)
            if status == 200:
                break
        except (OSError, http.client.HTTPException):
            pass
        if time.time() > deadline:
            raise SystemExit("no /healthz over HTTPS in 30 s")
        time.sleep(0.2)
    s, page = get(a.port, "/", ctx)
    report["page"] = [s, "skyfuse" in page, 'href="access"' in page]
    s, access = get(a.port, "/access", ctx)
    report["access"] = [s, "without a token" in access]
    s, body = get(a.port, "/api/v1/status", ctx)
    report["status"] = [s, json.loads(body)["service"]["name"]]
    try:
        c = http.client.HTTPConnection("127.0.0.1", a.port, timeout=3)
        c.request("GET", "/healthz")
        report["plain_http"] = c.getresponse().status
    except (OSError, http.client.HTTPException) as e:
        report["plain_http"] = f"refused: {type(e).__name__}"
    try:
        get(a.port, "/healthz", ssl.create_default_context())
        report["untrusted"] = "accepted"
    except ssl.SSLCertVerificationError as e:
        report["untrusted"] = f"refused: {e.reason}"
    print(json.dumps(report))


if __name__ == "__main__":
    main()
