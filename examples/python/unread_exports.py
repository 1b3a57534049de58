"""Peak RSS of a server while clients ask for state exports and never read them.

The attack of the hardening issue: each export's reply stays in the memory budget until it
is read, so once the budget is full the next export gets 429 instead of growing memory.

    target/release/afterimage scene fence --size 1280x720 --frames 1 --spp 1 -o /tmp/s720
    AFTERIMAGE_MEMORY_BUDGET_MIB=2048 target/release/afterimage serve &
    python3 examples/python/unread_exports.py 8080 $! /tmp/s720/frame_0000.exr

Standard library only; Linux (reads /proc/PID/status).
"""
import http.client
import json
import socket
import sys
import time


def main(http_port, pid, exr, exports=24):
    def req(method, path, body=b"", ctype="application/json"):
        c = http.client.HTTPConnection("127.0.0.1", http_port, timeout=600)
        c.request(method, path, body=body, headers={"Content-Type": ctype})
        r = c.getresponse()
        data = r.read()
        c.close()
        return r.status, data

    def mem():
        fields = dict(l.split(":", 1) for l in open(f"/proc/{pid}/status"))
        return int(fields["VmRSS"].split()[0]) // 1024, int(fields["VmHWM"].split()[0]) // 1024

    st, b = req("POST", "/v1/sessions", json.dumps({"filter": "phlm", "width": 1280, "height": 720}).encode())
    assert st == 201, (st, b)
    sid = json.loads(b)["id"]
    with open(exr, "rb") as f:
        st, b = req("POST", f"/v1/sessions/{sid}/frames", f.read(), "image/x-exr")
    assert st == 200, (st, b[:200])
    print("after one frame: RSS %d MiB, peak %d MiB" % mem())
    socks, codes = [], {}
    for _ in range(exports):
        s = socket.create_connection(("127.0.0.1", http_port))
        s.sendall(f"GET /v1/sessions/{sid}/state HTTP/1.1\r\nHost: x\r\n\r\n".encode())
        code = s.recv(64).decode(errors="replace")[9:12]
        codes[code] = codes.get(code, 0) + 1
        socks.append(s)
    time.sleep(3)
    print(f"{exports} unread exports: statuses {codes}, RSS %d MiB, peak %d MiB" % mem())
    for s in socks:
        s.close()
    time.sleep(1)
    print("closed: RSS %d MiB, peak %d MiB" % mem())


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])
