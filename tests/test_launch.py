"""ServerProcess: a model's server started for a run, waited for, and always stopped (real processes)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest

from conflictbench.core import ServerUnavailable, UserError
from conflictbench.hosting import ServerProcess, free_port

HEALTH_SERVER = textwrap.dedent(
    """
    import http.server, os, sys, time
    delay, port = float(sys.argv[1]), int(sys.argv[2])
    time.sleep(delay)  # loading a model
    class Health(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200 if self.path == "/healthz" else 404)
            self.end_headers()
            self.wfile.write(b"OK")
        def log_message(self, *args):
            pass
    print("serving", os.getpid(), flush=True)
    http.server.HTTPServer(("127.0.0.1", port), Health).serve_forever()
    """
)


def server(tmp_path, script: str, *args: str, timeout: float = 20.0) -> ServerProcess:
    port = free_port()
    argv = [sys.executable, "-c", script, *args, str(port)] if args else [sys.executable, "-c", script]
    return ServerProcess(
        argv, name="test", health_url=f"http://127.0.0.1:{port}/healthz", startup_timeout_s=timeout, log_dir=tmp_path
    )


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_start_waits_until_the_server_answers_and_stop_ends_it(tmp_path):
    process = server(tmp_path, HEALTH_SERVER, "1.0")
    started = time.monotonic()
    with process:
        assert time.monotonic() - started >= 1.0  # it waited for the load, not just for the process
        assert process.running
        pid = process.process.pid
        assert f"serving {pid}" in process.log_tail()
    assert not alive(pid)
    process.stop()  # twice is fine


def test_a_server_exiting_with_code_2_reports_its_last_line_as_a_user_error(tmp_path):
    script = "import sys; print('loading'); print('/x is a pi0 checkpoint: use model=pi0', file=sys.stderr); exit(2)"
    with pytest.raises(UserError, match=r"^/x is a pi0 checkpoint: use model=pi0$"):
        server(tmp_path, script).start()


def test_a_server_dying_while_starting_is_unavailable_and_names_its_log(tmp_path):
    process = server(tmp_path, "import sys; print('out of memory'); sys.exit(137)")
    with pytest.raises(ServerUnavailable, match=r"exited with code 137 while starting \(out of memory\)") as info:
        process.start()
    assert str(process.log_path) in str(info.value)


def test_a_server_that_never_answers_is_stopped_after_the_start_up_limit(tmp_path):
    process = server(tmp_path, "import time; print('stuck', flush=True); time.sleep(60)", timeout=1.5)
    with pytest.raises(ServerUnavailable, match="did not answer within 1.5 s"):
        process.start()
    assert process.process is None  # stopped, not left running
    assert "stuck" in process.log_tail()


def pid_of_the_server_of_a_run_that(tmp_path, ends_how: str) -> int:
    """Starts a run (a child Python) that starts a server, then ends as ``ends_how`` says; the server's pid."""
    port = free_port()
    child = textwrap.dedent(
        f"""
        import os, signal, sys
        from conflictbench.hosting import ServerProcess
        p = ServerProcess([sys.executable, "-c", {HEALTH_SERVER!r}, "0", "{port}"], name="test",
                          health_url="http://127.0.0.1:{port}/healthz", log_dir={str(tmp_path)!r}).start()
        print(p.process.pid, flush=True)
        {ends_how}
        """
    )
    out = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=60)
    return int(out.stdout.split()[0])


def ends_within(pid: int, seconds: float = 10.0) -> bool:
    deadline = time.monotonic() + seconds
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    return not alive(pid)


def test_a_run_that_dies_without_stopping_its_server_still_ends_it(tmp_path):
    assert ends_within(pid_of_the_server_of_a_run_that(tmp_path, "raise SystemExit(1)"))  # atexit stops it


def test_a_run_killed_outright_takes_its_server_with_it(tmp_path):
    # no atexit, no finally: the kernel must end the server
    assert ends_within(pid_of_the_server_of_a_run_that(tmp_path, "os.kill(os.getpid(), signal.SIGKILL)"))


def test_a_proxy_in_the_environment_does_not_catch_the_local_health_check(tmp_path, monkeypatch):
    monkeypatch.setenv("http_proxy", "http://127.0.0.1:9")  # nothing listens there
    monkeypatch.setenv("no_proxy", "")
    with server(tmp_path, HEALTH_SERVER, "0") as process:
        assert process.running


def test_a_servers_log_goes_where_the_run_says_not_to_the_temporary_directory(tmp_path, monkeypatch):
    """A run puts its servers' logs under its store (<run.out>/logs/servers), named in every failure."""
    from conflictbench.hosting.launch import SERVER_LOG_DIR_VARIABLE

    monkeypatch.setenv(SERVER_LOG_DIR_VARIABLE, str(tmp_path / "results" / "logs" / "servers"))
    process = ServerProcess(
        [sys.executable, "-c", "print('no model here'); exit(137)"], name="t", health_url="http://127.0.0.1:9/healthz"
    )
    with pytest.raises(ServerUnavailable, match="its log: " + str(tmp_path / "results" / "logs" / "servers")):
        process.start()
    assert process.log_path.read_text().strip() == "no model here"
