"""OpenPLC v3's own web page (webserver/webserver.py of a scratch copy), started in the private
network namespace the e2e tests run in and driven over HTTP as a browser drives it: the login
form with its CSRF token, "Upload Program", the program info form ("upload-program-action"),
the compile page and its log ("compilation-logs"), "Start PLC" on the dashboard.

The webserver binds 0.0.0.0:8080 (and its REST API 0.0.0.0:8443), hence the namespace. It runs
with the Python of the OpenPLC installation (the .venv its install.sh made; start_openplc.sh runs
`cd webserver; .venv/bin/python3 webserver.py`), from the scratch copy, so everything it writes
(its database, st_files/, core/, .env, restapi.db, certificates) lands in the copy.
"""
import contextlib
import os
import re
import signal
import sqlite3
import subprocess
import time

import requests

import oplc

PORT = 8080  # fixed in webserver.py (run_http)
BASE = f"http://127.0.0.1:{PORT}"
DONE_OK = "Compilation finished successfully!"
DONE_ERR = "Compilation finished with errors!"


class CompileError(AssertionError):
    """The page's compile log ended with errors; the message holds the whole log."""


def python(home):
    """The Python OpenPLC's install.sh set up for its webserver, or None."""
    p = os.path.join(home, ".venv", "bin", "python3")
    return p if os.access(p, os.X_OK) else None


def _query(web, sql, *args):
    """The first row of a query on the copy's database (read only)."""
    with contextlib.closing(sqlite3.connect(f"file:{os.path.join(web, 'openplc.db')}?mode=ro", uri=True)) as db:
        return db.execute(sql, args).fetchone()


def _hidden(page, name):
    """The value of the form field `name` on a page (OpenPLC writes value= before name/id=)."""
    m = re.search(r"value='([^']*)'\s+(?:id='[^']*'\s+)?name='%s'" % re.escape(name), page)
    assert m, f"no field {name!r} on the page:\n{page[:2000]}"
    return m.group(1)


class WebServer:
    """OpenPLC's webserver in a scratch copy (oplc.Scratch); a context manager. stop() presses
    Stop PLC, then ends the webserver and anything it started (the runtime) by its process group,
    whose id is the webserver's pid."""

    def __init__(self, scratch, timeout=120.0):
        if not oplc.in_private_netns():
            raise RuntimeError("refusing to start OpenPLC's webserver outside a private network "
                               "namespace (it binds every interface): run under tools/openplc/netns.sh")
        py = python(scratch.home)
        if not py:
            raise FileNotFoundError(f"{scratch.home}/.venv/bin/python3 (OpenPLC's webserver Python) not found")
        self.scratch = scratch
        self.http = requests.Session()
        port = _query(scratch.web, "SELECT Value FROM Settings WHERE Key = 'Modbus_port'")
        assert port and port[0].isdigit(), f"OpenPLC's Modbus server is not enabled in its settings: {port}"
        self.modbus_port = int(port[0])
        self.log = open(os.path.join(scratch.dir, "webserver.log"), "w+")
        t0 = time.monotonic()
        self.proc = subprocess.Popen([py, "-u", "webserver.py"], cwd=scratch.web, stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=oplc._die_with_parent)
        try:
            oplc.wait(self._answers, timeout, "OpenPLC's webserver to answer on port 8080")
        except AssertionError:
            self.stop()
            raise AssertionError("OpenPLC's webserver did not start:\n" + self.output())
        self.start_s = time.monotonic() - t0

    def _answers(self):
        if self.proc.poll() is not None:
            raise AssertionError("OpenPLC's webserver exited:\n" + self.output())
        try:
            return self.http.get(BASE + "/login", timeout=5).status_code == 200
        except requests.ConnectionError:
            return False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()

    def output(self):
        """What the webserver and the runtime it started printed."""
        if not self.log.closed:
            self.log.flush()
        with open(self.log.name, errors="replace") as f:
            return f.read()

    def get(self, path, **kw):
        r = self.http.get(BASE + path, timeout=60, **kw)
        r.raise_for_status()
        return r

    def post(self, path, **kw):
        r = self.http.post(BASE + path, timeout=60, **kw)
        r.raise_for_status()
        return r

    def login(self):
        """The login form with its CSRF token, as the OpenPLC user in the copy's database."""
        user, password = _query(self.scratch.web, "SELECT username, password FROM Users")
        token = _hidden(self.get("/login").text, "csrf_token")
        r = self.post("/login", data={"csrf_token": token, "username": user, "password": password})
        assert r.url.endswith("/dashboard"), f"login refused:\n{r.text[:2000]}"

    def upload(self, st_path, name):
        """Programs > Upload Program with the file, then the program info form; returns the
        file name OpenPLC gave the program (the compile page is where the form sends the
        browser: compile())."""
        token = _hidden(self.get("/programs").text, "csrf_token")
        with open(st_path, "rb") as f:
            page = self.post("/upload-program", data={"csrf_token": token, "submit": "Upload Program"},
                             files={"file": (os.path.basename(st_path), f, "application/octet-stream")}).text
        form = {k: _hidden(page, k) for k in ("prog_file", "epoch_time", "csrf_token")}
        form.update(prog_name=name, prog_descr="uploaded by tests/e2e/test_web.py")
        r = self.post("/upload-program-action", data=form)
        m = re.search(r"url=(/compile-program\?file=[^\"]+)\"", r.text)
        assert m, f"upload-program-action did not send the browser to the compile page:\n{r.text[:2000]}"
        self.compile_url = m.group(1)
        return form["prog_file"]

    def compile(self, timeout=600.0):
        """The compile page the upload form leads to, then its log until OpenPLC says it is
        done; returns the log, raises CompileError (with the log) when it ends with errors."""
        t0 = time.monotonic()
        assert "Compiling program" in self.get(self.compile_url).text
        log = oplc.wait(lambda: (lambda s: s if DONE_OK in s or DONE_ERR in s else None)(
            self.get("/compilation-logs").text), timeout, "the compile log to say it finished")
        self.compile_s = time.monotonic() - t0
        if DONE_OK not in log:
            raise CompileError("OpenPLC's page could not compile the program; its compile log:\n" + log)
        return log

    def start_plc(self, timeout=60.0):
        """Dashboard > Start PLC; returns once the runtime's Modbus server listens. OpenPLC sends
        start_modbus one second after it starts the runtime; a command that reaches the runtime
        as its interactive server starts listening can be lost (see oplc.Scratch.start): the log
        then never shows it taken, and Stop PLC / Start PLC, as a user would, tries again."""
        taken = f"Issued start_modbus() command to start on port: {self.modbus_port}"
        listening = f"Server: Listening on port {self.modbus_port}"
        for attempt in range(3):
            assert "Start PLC" in self.get("/dashboard").text
            self.get("/start_plc")
            try:
                oplc.wait(lambda: taken in self.get("/runtime_logs").text, timeout,
                          "the runtime to take start_modbus")
            except AssertionError:
                print(f"start_modbus was not taken (attempt {attempt + 1}): Stop PLC, Start PLC")
                self.get("/stop_plc")
                continue
            oplc.wait(lambda: listening in self.get("/runtime_logs").text, timeout,
                      "the runtime's Modbus server to listen")
            assert "Running" in self.get("/dashboard").text
            return
        raise AssertionError("Start PLC never started the Modbus server:\n" + self.output()[-4000:])

    def stop(self):
        if self.proc.poll() is None:
            try:
                self.http.get(BASE + "/stop_plc", timeout=30)
            except requests.RequestException:
                pass
            for sig in (signal.SIGTERM, signal.SIGKILL):
                try:
                    os.killpg(self.proc.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.proc.wait(timeout=10)
                    break
                except subprocess.TimeoutExpired:
                    pass
        self.proc.wait()
        try:  # the runtime, if it outlived the webserver
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.http.close()
        self.log.close()
