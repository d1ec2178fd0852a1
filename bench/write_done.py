"""Write Done: does a write's Done come in the first scan after its reply?

    .venv/bin/python bench/write_done.py                  # 4 cases x 30 s: about 4.5 min here
    .venv/bin/python bench/write_done.py --seconds 10 --intervals 20

Not a test: it prints figures (bench/README.md, "Write Done"). One MV-D94 (TempCtrl_MVD94) at
9600 8N2 on a line paced by ptyline (tools/sim/ptyline, 1..10 ms device turnaround, seeded: the
line and simulator of bench/rig.py, whose helpers this script imports). An ST program,
built as OpenPLC builds it (iec2c, g++ -O0) and run in real time by bench/wirepace/wp_host.cpp
(SCHED_FIFO like OpenPLC), raises WriteSV with a new set point (100, 101, ... as raw counts,
DP 0) --every scans after the previous write ended, and marks (wp_mark) the scan in which
Execute rose and the scan in which SVDone (or SVError) rose. Cases: Period T#0s (the plan
keeps the line busy: a write waits for the transaction on the wire) and a long Period (idle
bus: the write is alone; that case warms up for Period + 1.5 s, as the block is Valid from
its second refresh), each at task intervals 20 and 100 ms.

From ptyline's frame log: each write's FC06 request (matched by the value it carries) and
its reply (the S>M frame right after it, an echo = success). Per write:
  lag  = scans that STARTED between the reply's last byte on the wire and the scan that saw
         Done (0 = Done in the first scan after the reply);
  false Done = Done seen in a scan that started before the reply ended (must be 0);
  Execute -> request = scans started between the Execute scan and the request's first byte;
  Execute -> Done in scans and in ms (scan start to scan start).

Clocks. The host stamps scan starts with CLOCK_MONOTONIC; ptyline stamps frames with
CLOCK_MONOTONIC too, but logs them relative to its own start t0, which it does not print.
t0 is bracketed by probes: before the first case and after each, this script reads one
register of the MV-D94 five times as the line's master (the line is otherwise idle then).
A request cannot be on the wire before it was written, so t0 >= (monotonic time just
before the write) - (the request's logged start); the reply's last byte reaches the master
at its end on the wire, never before, so t0 <= (monotonic time just after reading it) -
(the reply's logged end). Also t0 <= the moment this script read ptyline's port lines
(ptyline reads t0 before printing them), and every write's request cannot start before the
scan that posted it. The figures use the middle of the bracket; a write whose lag or
false-Done verdict differs between the two ends of the bracket is counted as "ambiguous".
The bracket's width is printed per case.
"""
from __future__ import annotations

import argparse
import json
import os
import select
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rig as wp  # noqa: E402  (its Variant, Line, CONFIG, host_json, log)
from modsim.frames import crc_bytes  # noqa: E402  (tools/sim, on the path through rig)

SV_BASE = 100              # set points written: SV_BASE + (k MOD 1000), raw counts at DP 0


def program(port: str, period: str, every: int) -> str:
    return f"""
PROGRAM main
  VAR
    l : MB_LINE := (Baud := 9600, Parity := 'N', StopBits := 2);
    dev : TempCtrl_MVD94;
    ws : BOOL;
    sv : REAL;
    k : INT;
    tag : INT;
    idle : INT;
  END_VAR
  idle := idle + 1;
  IF NOT ws AND idle >= {every} AND dev.Valid AND NOT dev.SVBusy THEN
    k := k + 1;
    tag := {SV_BASE} + (k MOD 1000);
    sv := INT_TO_REAL(tag);
    ws := TRUE;
    {{{{ wp_mark(1, GetFbVar(TAG)); }}}}
  END_IF;
  dev(Enable := TRUE, Port := '{port}', SlaveId := 1, Line := l, Period := {period},
      WriteSV := ws, SVSet := sv);
  IF ws AND dev.SVDone THEN
    {{{{ wp_mark(2, GetFbVar(TAG)); }}}}
    ws := FALSE;
    idle := 0;
  ELSIF ws AND dev.SVError THEN
    {{{{ wp_mark(3, GetFbVar(TAG)); }}}}
    ws := FALSE;
    idle := 0;
  END_IF;
END_PROGRAM
""" + wp.CONFIG


def probe(line: wp.Line, first: int, reps: int = 5) -> list[tuple[int, int, bytes, int, int]]:
    """On the idle line, as its master: `reps` FC03 reads of 2 registers from 0x30 + first,
    0x31 + first, ... (words the blocks never read: each request is a unique frame) from the
    MV-D94. Returns per exchange (CLOCK_MONOTONIC ns just before writing the request, just
    after reading the reply's last byte, the request, and the range of frame-log indexes the
    probes' frames are in)."""
    out = []
    n0 = len(frames(line.logf))
    fd = os.open(line.m, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        time.sleep(0.1)                # ptyline notices an opener within ~10 ms
        for n in range(first, first + reps):
            a, c = 0x30 + n % 0x40, 2 + n // 0x40   # unique, inside the FC03 window 0..0x7D
            frame = bytes((1, 3, 0, a, 0, c))
            frame += crc_bytes(frame)
            got = b""
            tw = time.monotonic_ns()
            os.write(fd, frame)
            tr, limit = None, time.monotonic() + 0.5
            while len(got) < 5 + 2 * c and time.monotonic() < limit:
                if select.select([fd], [], [], 0.05)[0]:
                    got += os.read(fd, 64)
                    tr = time.monotonic_ns()
            if len(got) != 5 + 2 * c or got[:3] != bytes((1, 3, 2 * c)):
                raise SystemExit(f"probe: register {a}: no reply from the simulated MV-D94 ({got.hex(' ')})")
            out.append((tw, tr, frame))
            time.sleep(0.03)
    finally:
        os.close(fd)
    time.sleep(0.1)                    # ptyline logs a frame after its t3.5 of silence
    n1 = len(frames(line.logf))
    return [x + (n0, n1) for x in out]


def frames(path: str) -> list[tuple[float, str, bytes]]:
    """ptyline's frame log: [(start_us from t0, 'M>S'|'S>M' (+'*' on a collision), bytes)]."""
    out = []
    with open(path, encoding="utf-8") as fh:
        for ln in fh:
            p = ln.split()
            if len(p) >= 3 and "..." not in ln:
                out.append((float(p[0]), p[1], bytes(int(x, 16) for x in p[2:])))
    return out


def analyse(line: wp.Line, host: dict, probes: list[tuple[int, int, bytes, int, int]], ready_ns: int, tail_s: float,
            first: int):
    """One case; its frames are those from index `first` of the log on (the probes: all)."""
    allfr = frames(line.logf)
    fr = allfr[first:]
    char_ns = line.char_us * 1000
    # t0 bracket: from each probe exchange, t0 >= (write time - request's start) and
    # t0 <= (read time - reply's end); also t0 <= ready (ptyline reads t0 before printing)
    lo, hi = -float("inf"), float(ready_ns)
    for tw, tr, fb, n0, n1 in probes:
        for j in range(n0, min(n1, len(allfr))):
            f = allfr[j]
            if f[1] == "M>S" and f[2] == fb:
                lo = max(lo, tw - f[0] * 1000)
                if j + 1 < len(allfr) and allfr[j + 1][1] == "S>M":
                    hi = min(hi, tr - (allfr[j + 1][0] * 1000 + len(allfr[j + 1][2]) * char_ns))
    scan = host["scan_ns"]
    w0, w1 = host["window_ns"]
    # writes: Execute mark -> the next Done/Error mark with the same tag
    writes, open_ = [], {}
    for what, tag, s in host["marks"]:
        if what == 1:
            open_[tag] = {"tag": tag, "exec": s, "end": None, "ok": None}
            writes.append(open_[tag])
        elif tag in open_ and open_[tag]["end"] is None:
            open_[tag]["end"], open_[tag]["ok"] = s, what == 2
    # wire: FC06 requests to slave 1, SV register, and the frame right after each
    reqs = []
    for i, (t, d, b) in enumerate(fr):
        if d.startswith("M>S") and len(b) == 8 and b[0] == 1 and b[1] == 6 and b[2:4] == b"\0\0":
            nxt = fr[i + 1] if i + 1 < len(fr) else None
            echo = nxt is not None and nxt[1] == "S>M" and nxt[2] == b
            reqs.append({"i": i, "t": t * 1000, "val": b[4] << 8 | b[5],
                         "reply_end": (nxt[0] * 1000 + len(nxt[2]) * char_ns) if nxt and nxt[1] == "S>M" else None,
                         "echo": echo})
    # pair each write with its request(s) (the same value again: the shims sent it again), in
    # order, from after the previous write's last one
    ri = 0
    for w in writes:
        w["reqs"] = []
        j = next((j for j in range(ri, len(reqs)) if reqs[j]["val"] == w["tag"]), None)
        while j is not None and j < len(reqs) and reqs[j]["val"] == w["tag"]:   # a write not sent: none
            w["reqs"].append(reqs[j])
            j += 1
            ri = j
    for w in writes:                   # causality: a request starts after the scan that posted it
        if w["reqs"]:
            lo = max(lo, scan[w["exec"]] - w["reqs"][0]["t"])
    measured = [w for w in writes if w0 <= scan[w["exec"]] and scan[w["exec"]] <= w1 - tail_s * 1e9]

    def lag(w, t0):
        """(scans started between the reply's end and the Done scan, Done before reply end)"""
        r = w["good"]
        end = t0 + r["reply_end"]
        d = scan[w["end"]]
        n = sum(1 for i in range(w["exec"], w["end"]) if end < scan[i])
        return n, d <= end

    res = {"t0_width_us": (hi - lo) / 1000 if lo > -float("inf") else float("nan"),
           "clock_bad": lo > hi, "n": len(measured), "no_done": 0, "errors": 0, "no_request": 0,
           "lag": [], "ambiguous": 0, "false_done": 0, "exec_req_scans": [], "exec_req_ms": [],
           "exec_done_scans": [], "exec_done_ms": [], "retries": 0,
           "late": [], "reply_to_done_ms": [], "retried": [], "lag0_us": []}
    mid = (lo + hi) / 2
    for w in measured:
        if w["end"] is None:
            res["no_done"] += 1
            continue
        if not w["ok"]:
            res["errors"] += 1
            continue
        good = [r for r in w["reqs"] if r["echo"]]
        if not good:
            res["no_request"] += 1
            continue
        w["good"] = good[-1]
        res["retries"] += len(w["reqs"]) - 1
        if len(w["reqs"]) > 1:             # what the wire shows between the first request and the last reply
            a, b = w["reqs"][0]["i"], w["reqs"][-1]["i"] + 2
            res["retried"].append({"tag": w["tag"], "frames": [
                f"{(mid + t * 1000 - scan[w['exec']]) / 1e6:.1f} ms {d} {b_.hex(' ')}" for t, d, b_ in fr[a:b]]})
        (a, fa), (b, fb), (m, fm) = lag(w, lo), lag(w, hi), lag(w, mid)
        if (a, fa) != (b, fb):
            res["ambiguous"] += 1
        res["false_done"] += fm
        res["lag"].append(m)
        reply_end = mid + w["good"]["reply_end"]
        first = next((scan[i] for i in range(w["exec"], len(scan)) if scan[i] > reply_end), None)
        if m > 0:
            res["late"].append({"tag": w["tag"], "lag": m, "first_scan_after_reply_us":
                                (first - reply_end) / 1000 if first is not None else None,
                                "done_scan_after_reply_ms": (scan[w["end"]] - reply_end) / 1e6})
        req_start = mid + w["reqs"][0]["t"]
        res["exec_req_scans"].append(sum(1 for i in range(w["exec"] + 1, len(scan)) if scan[i] < req_start))
        res["exec_req_ms"].append((req_start - scan[w["exec"]]) / 1e6)
        res["exec_done_scans"].append(w["end"] - w["exec"])
        res["exec_done_ms"].append((scan[w["end"]] - scan[w["exec"]]) / 1e6)
        res["reply_to_done_ms"].append((scan[w["end"]] - reply_end) / 1e6)
        if m == 0 and not fm:
            res["lag0_us"].append((scan[w["end"]] - reply_end) / 1000)
    # other traffic in the window (is the line busy or idle?)
    res["other_tx_s"] = sum(1 for t, d, b in fr if d.startswith("M>S") and not (len(b) == 8 and b[1] == 6)
                            and b[0] == 1 and w0 <= mid + t * 1000 < w1) / ((w1 - w0) / 1e9)
    res["unanswered"] = [f"{b.hex(' ')}" for i, (t, d, b) in enumerate(fr[:-1])
                         if d.startswith("M>S") and b[0] == 1 and not fr[i + 1][1].startswith("S>M")]
    res["collisions"] = sum(1 for t, d, b in fr if d.endswith("*") and w0 <= mid + t * 1000 < w1)
    echoed = [r["val"] for r in reqs if r["echo"]]
    res["last_wire"] = echoed[-1] if echoed else None
    return res


def dist(values, top=2) -> str:
    """'0: a, 1: b, 2+: c'"""
    c = [sum(1 for v in values if v == i) for i in range(top)] + [sum(1 for v in values if v >= top)]
    return ", ".join(f"{i}{'+' if i == top else ''}: {n}" for i, n in enumerate(c))


def q(values, p):
    s = sorted(values)
    return s[min(len(s) - 1, int(p * (len(s) - 1) + 0.5))] if s else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="measuring window per case")
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--intervals", default="20,100", help="task intervals, ms")
    ap.add_argument("--long-period", type=int, default=60, help="the idle-bus case's Period, s")
    ap.add_argument("--every", type=int, default=3, help="scans from one write's end to the next Execute")
    ap.add_argument("--tail", type=float, default=1.0,
                    help="writes raised in the window's last TAIL s are not counted (may still be running)")
    ap.add_argument("--keep", metavar="DIR", help="keep ptyline's frame log, the host's JSON lines and the simulator's logs there")
    args = ap.parse_args()
    try:
        intervals = [int(x) for x in args.intervals.split(",") if x]
    except ValueError:
        raise SystemExit(f"--intervals wants milliseconds like 20,100, not '{args.intervals}'") from None
    if (not intervals or min(intervals) <= 0 or args.seconds <= args.tail or args.warmup < 0
            or args.tail < 0 or args.every < 2 or args.long_period <= 0):
        raise SystemExit("bad arguments: intervals > 0, seconds > tail >= 0, warmup >= 0, every >= 2, "
                         "long-period > 0 (see --help)")
    if args.keep and not os.path.isdir(args.keep):
        raise SystemExit(f"--keep {args.keep}: not a directory")
    tmp = wp.tempfile.mkdtemp(prefix="writedone-")
    started = time.monotonic()
    rows = []
    try:
        v = wp.Variant("now", "worktree", tmp)
        port = os.path.join(tmp, "mv")
        cases = [("T#0s", "busy line"), (f"T#{args.long_period}s", "idle line")]
        # The block is Valid from its second refresh (the first sets the DP reference:
        # st_src/README.md), one Period after the first: the idle case warms up that long.
        warm = [args.warmup, max(args.warmup, args.long_period + 1.5)]
        wp.log("compiling the ST programs (iec2c, g++ -O0) ...")
        for i, (period, _) in enumerate(cases):
            v.compile(f"w{i}", program(port, period, args.every))
        line = wp.Line(v.ptyline, tmp, "mv", 9600, "8N2", ["mvd94:1"])
        ready_ns = int(line.ready * 1e9)
        try:
            probes = probe(line, 0)
            line.sim.control({"op": "log", "clear": True})
            for i, (period, what) in enumerate(cases):
                for ms in intervals:
                    wp.log(f"Period {period} ({what}), task {ms} ms: {warm[i]:g} + {args.seconds:g} s")
                    first = len(frames(line.logf))
                    p = wp.subprocess.run([v.programs[f"w{i}"], str(warm[i]), str(args.seconds), str(ms)],
                                          capture_output=True, text=True,
                                          timeout=warm[i] + args.seconds + 60)
                    if p.returncode != 0:
                        raise SystemExit(f"program exited {p.returncode}:\n{p.stderr[-2000:]}")
                    host = wp.host_json(p.stdout)
                    simlog = line.sim.control({"op": "log", "clear": True})["frames"]
                    if "marks" not in host:
                        raise SystemExit(f"Period {period}, task {ms} ms: no write was raised "
                                         "(the block never Valid?)")
                    time.sleep(0.2)                          # let ptyline log the last frames
                    probes += probe(line, len(probes))
                    if args.keep:
                        with open(os.path.join(args.keep, f"host-{period[2:]}-{ms}ms.json"), "w",
                                  encoding="utf-8") as fh:
                            fh.write(p.stdout)
                        with open(os.path.join(args.keep, f"sim-{period[2:]}-{ms}ms.json"), "w",
                                  encoding="utf-8") as fh:
                            json.dump(simlog, fh)
                    r = analyse(line, host, probes, ready_ns, args.tail, first)
                    r.update(period=period, what=what, ms=ms, rt=host["rt"], scans=host["scans"])
                    # what the simulator made of frames it did not answer (its log of this case)
                    r["sim_notes"] = [f"{e['hex']} ({e['info']})" for e in simlog
                                      if e.get("dir") == "rx" and e.get("info")]
                    cf = frames(line.logf)[first:]
                    r["counts"] = (sum(1 for e in simlog if e.get("dir") == "rx"),
                                   sum(1 for e in simlog if e.get("dir") == "tx"),
                                   sum(1 for t, d, b in cf if d.startswith("M>S") and b[0] == 1),
                                   sum(1 for t, d, b in cf if d.startswith("S>M")), len(simlog) >= 4000)
                    rows.append(r)
            sv = line.sim.control({"op": "get", "addr": 1, "reg": "SV"})
        finally:
            line.close()
            if args.keep:
                wp.shutil.copy(line.logf, os.path.join(args.keep, "frames.log"))
    finally:
        wp.shutil.rmtree(tmp, ignore_errors=True)
    report(rows, args, sv)
    wp.log(f"total {time.monotonic() - started:.0f} s")
    return 0


def report(rows, args, sv) -> None:
    print(f"# Write Done: one MV-D94, 9600 8N2 on ptyline, TempCtrl_MVD94 WriteSV every {args.every} scans "
          f"after the previous write ended; window {args.seconds:g} s after {args.warmup:g} s\n")
    print("| Period | task ms | writes | lag: scans between reply end and Done scan | false Done | "
          "without Done | errors | Execute -> request: scans | wait for the line ms median / max | "
          "Execute -> Done scans median (min-max) | ms median / p95 / max | reply end -> Done scan start "
          "ms median / max | ambiguous | t0 bracket us | other tx/s | SCHED_FIFO |")
    print("|---" * 16 + "|")
    for r in rows:
        ed = r["exec_done_scans"]
        print(f"| {r['period']} ({r['what']}) | {r['ms']} | {r['n']} | {dist(r['lag'])} | {r['false_done']} | "
              f"{r['no_done']} | {r['errors']} | {dist(r['exec_req_scans'])} | "
              f"{q(r['exec_req_ms'], .5):.1f} / {q(r['exec_req_ms'], 1):.1f} | "
              f"{q(ed, .5)} ({min(ed, default=0)}-{max(ed, default=0)}) | "
              f"{q(r['exec_done_ms'], .5):.1f} / {q(r['exec_done_ms'], .95):.1f} / {q(r['exec_done_ms'], 1):.1f} | "
              f"{q(r['reply_to_done_ms'], .5):.1f} / {q(r['reply_to_done_ms'], 1):.1f} | {r['ambiguous']} | "
              f"{r['t0_width_us']:.0f}{' INCONSISTENT' if r['clock_bad'] else ''} | {r['other_tx_s']:.1f} | "
              f"{'yes' if r['rt'] else 'no'} |")
    extra = [f"{r['period']}/{r['ms']} ms: {r['retries']} retries, {r['no_request']} Done without an "
             f"echoed request, {r['collisions']} collisions" for r in rows
             if r["retries"] or r["no_request"] or r["collisions"]]
    print("\n" + ("; ".join(extra) + "." if extra else "No retries, no collisions, every Done has its echoed request."))
    for r in rows:
        if r["unanswered"] or r["sim_notes"]:
            rx, tx, req, rep, full = r["counts"]
            print(f"{r['period']}/{r['ms']} ms: requests without a reply on the wire: "
                  f"{'; '.join(r['unanswered']) or 'none'}; the simulator's notes on frames it received: "
                  f"{'; '.join(r['sim_notes']) or 'none'}; requests on the wire {req}, frames the simulator "
                  f"received {rx}; replies it sent {tx}, on the wire {rep}{' (its log was full)' if full else ''}.")
    print("Quickest Done in the first scan after its reply (that scan started this long after the "
          "reply's end): " + ", ".join(f"{r['period']}/{r['ms']} ms {min(r['lag0_us'], default=float('nan')):.0f} us"
                                       for r in rows) + ".")
    for r in rows:
        for x in r["late"]:
            print(f"late Done, {r['period']}/{r['ms']} ms: value {x['tag']}, lag {x['lag']} scans; first scan "
                  f"started {x['first_scan_after_reply_us']:.0f} us after the reply's end, Done scan "
                  f"{x['done_scan_after_reply_ms']:.1f} ms after it")
    for r in rows:
        for x in r["retried"]:
            print(f"retried write, {r['period']}/{r['ms']} ms: value {x['tag']}; the wire from its first request "
                  f"(ms after its Execute scan): " + "; ".join(x["frames"]))
    last = rows[-1]["last_wire"] if rows else None
    print(f"\nSimulator's SV at the end: {sv.get('raw')}; the last set point acknowledged on the wire: {last}.")


if __name__ == "__main__":
    sys.exit(main())
