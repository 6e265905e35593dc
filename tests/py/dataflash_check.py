"""Reads an ArduPilot DataFlash log with pymavlink's DFReader (the reader MAVProxy,
MAVExplorer and most log tools use) and prints, as JSON, what it found: the number of
records of each type, and the first and last record of each type with every numeric
field. The Rust test compares this with skyfuse's own reader on the same file.

usage: dataflash_check.py FILE.bin
"""
import json
import math
import sys

from pymavlink import DFReader


def numeric(msg):
    out = {}
    for k, v in msg.to_dict().items():
        if k == "mavpackettype" or isinstance(v, (str, bytes)) or isinstance(v, bool):
            continue
        if isinstance(v, (int, float)) and math.isfinite(v):
            out[k] = v
    return out


def main():
    log = DFReader.DFReader_binary(sys.argv[1], zero_time_base=True)
    counts, first, last = {}, {}, {}
    while True:
        m = log.recv_msg()
        if m is None:
            break
        t = m.get_type()
        if t in ("FMT", "FMTU", "UNIT", "MULT"):
            continue
        counts[t] = counts.get(t, 0) + 1
        fields = numeric(m)
        first.setdefault(t, fields)
        last[t] = fields
    print(json.dumps({"counts": counts, "first": first, "last": last}))


if __name__ == "__main__":
    main()
