"""OctoPrint plugin: rewrite uploaded G-code for an asymmetric nozzle on a rotary axis.

Every OctoPrint call lives in this module (the work is :mod:`octoprint_printability.core`,
which does not import OctoPrint), so the changes of OctoPrint's 2.0 line are followed here:
the deprecated calls it replaces (``get_current_connection``, ``is_current_file``) are used
through :meth:`PrintabilityPlugin._port` and :meth:`PrintabilityPlugin._printing_file`,
which try the 2.0 names first.

What it does:

- a settings page (nozzle SPEC with a drawing, machine, what to do with uploads, rotary
  firmware flavor), each value checked by printability's own parser or registry; a value
  refused keeps the one before and the reason is shown in one paragraph;
- an uploaded G-code file (``FileAdded``) is rewritten in a background thread by the function
  ``printability postprocess`` calls, into ``NAME.rotary.gcode`` beside it (the upload is
  never touched); progress and errors reach the UI as plugin messages;
- ``GET /api/plugin/printability?path=FILE``: the summary of a rewrite (lost area per layer,
  what could not be printed, the print time before and after); ``/plugin/printability/
  summary?path=FILE`` the same as a page, and ``/plugin/printability/report/…`` the HTML
  report of ``printability analyze``, made on request;
- on connect, the printer's M115 and M114 replies are checked for the rotary axis, with the
  message ``printability stream`` gives.
"""

from __future__ import annotations

import collections
import hashlib
import os
import queue
import shutil
import threading
import time
import uuid
from typing import Any

import flask
import octoprint.plugin
from octoprint.events import Events
from octoprint.filemanager import FileDestinations, valid_file_type
from octoprint.filemanager.util import DiskFileWrapper

from octoprint_printability import core

__all__ = ["PrintabilityPlugin"]

LOCAL = FileDestinations.LOCAL
META_KEY = "printability"
_AXIS_WAIT = 5.0  # s: without an M114 reply by then, the check uses M115 alone


class PrintabilityPlugin(
    octoprint.plugin.StartupPlugin,
    octoprint.plugin.ShutdownPlugin,
    octoprint.plugin.SettingsPlugin,
    octoprint.plugin.TemplatePlugin,
    octoprint.plugin.AssetPlugin,
    octoprint.plugin.EventHandlerPlugin,
    octoprint.plugin.SimpleApiPlugin,
    octoprint.plugin.BlueprintPlugin,
):
    """The plugin: settings, the upload rewrites (one background thread, one job at a time),
    the status API, the summary and report pages and the connect check (module docstring)."""

    def __init__(self) -> None:
        self._queue: queue.Queue = queue.Queue()
        self._jobs: dict[str, dict[str, Any]] = {}
        self._jobs_lock = threading.Lock()
        self._events: collections.deque = collections.deque(maxlen=100)
        self._worker: threading.Thread | None = None
        self._stop = threading.Event()
        self._idle = threading.Event()  # set while no print runs
        self._idle.set()
        self._fw = core.FirmwareReport()
        self._axis: dict[str, Any] = {"state": "unknown", "message": None}
        self._axis_timer: threading.Timer | None = None
        self._fw_lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def on_after_startup(self) -> None:
        """Start the rewriting thread."""
        self._worker = threading.Thread(target=self._work, name="printability", daemon=True)
        self._worker.start()
        self._logger.info("printability: uploads %s, nozzle %r, machine %r",
                          self._settings.get(["uploads"]), self._settings.get(["nozzle"]),
                          self._settings.get(["machine"]))

    def on_shutdown(self) -> None:
        """Stop the rewriting thread (a rewrite under way ends with OctoPrint's process)."""
        self._stop.set()
        self._queue.put(None)

    def _data(self) -> str:
        return self.get_plugin_data_folder()

    def _current(self) -> dict[str, Any]:
        return {k: self._settings.get([k]) for k in core.DEFAULTS}

    # ------------------------------------------------------------------ settings
    def get_settings_defaults(self) -> dict[str, Any]:
        """:data:`core.DEFAULTS`: no nozzle (nothing rewritten), ``ttr``, auto, auto."""
        return dict(core.DEFAULTS)

    def on_settings_save(self, data: dict[str, Any]) -> dict[str, Any]:
        """Store the values printability's parsers accept; a refused one keeps the value
        before, and the reason is a notification (one paragraph)."""
        accepted, refused = core.check_settings(data, base_dir=self._data())
        for key, message in refused.items():
            old = self._settings.get([key])
            self._notify("error", f"printability: {key} refused",
                         f"{message} (the {key} stays {old!r})", kind="settings",
                         extra={"key": key, "value": data.get(key), "message": message})
        saved = octoprint.plugin.SettingsPlugin.on_settings_save(self, accepted)
        if "machine" in accepted or "nozzle" in accepted:
            self._axis_check_later(0.0)
        return saved

    # ------------------------------------------------------------------ templates, assets
    def get_template_configs(self) -> list[dict[str, Any]]:
        """The settings page and the *Rotary nozzle* tab (bound by static/js)."""
        return [
            {"type": "settings", "custom_bindings": True, "name": "printability"},
            {"type": "tab", "custom_bindings": True, "name": "Rotary nozzle"},
        ]

    def get_template_vars(self) -> dict[str, Any]:
        """The choices of the settings page's lists, from printability's registries."""
        return {
            "upload_modes": [{"value": k, "text": f"{k}: {v}"}
                             for k, v in core.UPLOAD_MODES.items()],
            "flavors": core.flavor_choices(),
        }

    def is_template_autoescaped(self) -> bool:
        """Jinja escapes what the templates print."""
        return True

    def get_assets(self) -> dict[str, list[str]]:
        """The view model and the style sheet."""
        return {"js": ["js/printability.js"], "css": ["css/printability.css"]}

    # ------------------------------------------------------------------ messages
    def _send(self, payload: dict[str, Any]) -> None:
        self._plugin_manager.send_plugin_message(self._identifier, payload)

    def _notify(self, level: str, title: str, text: str, *, kind: str = "job",
                extra: dict[str, Any] | None = None) -> None:
        """A notification in the UI (one paragraph), kept for the status API too."""
        text = " ".join(str(text).split())
        event = {"type": "notify", "level": level, "title": title, "text": text,
                 "kind": kind, "time": time.time(), **(extra or {})}
        self._events.append(event)
        log = self._logger.error if level == "error" else self._logger.info
        log("%s: %s", title, text)
        self._send(event)

    # ------------------------------------------------------------------ uploads
    def on_event(self, event: str, payload: dict[str, Any]) -> None:
        """Uploads (rewritten in the background), connects (the axis check), prints (a
        rewrite waits until the print ends)."""
        if event == Events.FILE_ADDED:
            self._on_file_added(payload or {})
        elif event == Events.CONNECTED:
            with self._fw_lock:
                self._axis = {"state": "checking", "message": None}
            # M115 went out with the connect; M114 names the axes
            self._printer.commands("M114", tags={"trigger:plugin.printability.axis_check"})
            self._axis_check_later(_AXIS_WAIT)
        elif event in (Events.DISCONNECTED,):
            with self._fw_lock:
                self._fw = core.FirmwareReport()
                self._axis = {"state": "unknown", "message": None}
        elif event == Events.PRINT_STARTED:
            self._idle.clear()
            self._check_job_axis(payload or {})
        elif event in (Events.PRINT_DONE, Events.PRINT_FAILED, Events.PRINT_CANCELLED):
            self._idle.set()

    def _on_file_added(self, payload: dict[str, Any]) -> None:
        storage, path = payload.get("storage"), payload.get("path")
        name = payload.get("name") or os.path.basename(path or "")
        if storage != LOCAL or not path or not valid_file_type(path, type="gcode"):
            return
        if core.is_rotary_output(name):
            return  # ours (or named like ours): never rewritten again
        mode = self._settings.get(["uploads"])
        if mode != "auto":
            return
        if not self._settings.get(["nozzle"]):
            self._notify("info", "printability: no nozzle set",
                         f"{name} was not rewritten: set the installed nozzle in Settings → "
                         "printability first.", kind="upload", extra={"path": path})
            return
        self.enqueue("rewrite", path)

    def enqueue(self, kind: str, path: str) -> dict[str, Any]:
        """Queue a ``"rewrite"`` or a ``"report"`` of the local file ``path``; returns the
        job (its ``id`` names it in the progress messages and the API)."""
        job = {"id": uuid.uuid4().hex[:12], "kind": kind, "path": path,
               "name": os.path.basename(path), "state": "queued", "stage": "queued",
               "queued": time.time(), "elapsed": 0.0, "output": None, "error": None,
               "report": None}
        with self._jobs_lock:
            self._jobs[job["id"]] = job
            if len(self._jobs) > 200:
                for old in list(self._jobs)[:50]:
                    if self._jobs[old]["state"] in ("done", "failed", "skipped"):
                        del self._jobs[old]
        self._progress(job, "queued")
        self._queue.put(job["id"])
        return job

    def _progress(self, job: dict[str, Any], stage: str, **more: Any) -> None:
        job["stage"] = stage
        job.update(more)
        self._send({"type": "progress", "job": job["id"], "kind": job["kind"],
                    "path": job["path"], "name": job["name"], "state": job["state"],
                    "stage": stage, "elapsed": round(job["elapsed"], 1),
                    "output": job["output"]})

    def _work(self) -> None:
        while not self._stop.is_set():
            job_id = self._queue.get()
            if job_id is None:
                return
            job = self._jobs.get(job_id)
            if job is None:
                continue
            if not self._idle.is_set():
                job["state"] = "waiting"
                self._progress(job, "waiting for the print to end")
                while not self._idle.wait(1.0):
                    if self._stop.is_set():
                        return
            job["state"] = "running"
            t0 = time.monotonic()
            beat = threading.Event()

            def heartbeat(job=job, t0=t0, beat=beat) -> None:
                while not beat.wait(1.0):
                    job["elapsed"] = time.monotonic() - t0
                    self._progress(job, job["stage"])

            ticker = threading.Thread(target=heartbeat, name="printability-progress",
                                      daemon=True)
            ticker.start()
            try:
                if job["kind"] == "report":
                    self._run_report(job)
                else:
                    self._run_rewrite(job)
            except Exception as exc:
                job["state"] = "failed"
                job["error"] = core.one_paragraph(exc, name=job["path"],
                                                  disk_path=job.get("disk_path"))
                if not isinstance(exc, core.PrintabilityError):
                    self._logger.exception("printability: %s of %s failed", job["kind"],
                                           job["path"])
                self._mark_source(job, {"status": "failed", "error": job["error"]})
                self._notify("error", f"printability: {job['name']} not rewritten"
                             if job["kind"] == "rewrite" else
                             f"printability: no report for {job['name']}", job["error"],
                             extra={"job": job["id"], "path": job["path"]})
            finally:
                beat.set()
                ticker.join()
                job["elapsed"] = time.monotonic() - t0
                self._progress(job, job["state"])

    def _mark_source(self, job: dict[str, Any], data: dict[str, Any]) -> None:
        if job["kind"] != "rewrite":
            return
        try:
            if self._file_manager.file_exists(LOCAL, job["path"]):
                self._file_manager.set_additional_metadata(
                    LOCAL, job["path"], META_KEY, {**data, "time": time.time()},
                    overwrite=True)
        except Exception:
            self._logger.exception("printability: cannot note the outcome on %s", job["path"])

    def _run_rewrite(self, job: dict[str, Any]) -> None:
        fm = self._file_manager
        path = job["path"]
        if not fm.file_exists(LOCAL, path):
            raise core.PrintabilityError(f"{job['name']} is no longer in OctoPrint's files; "
                                         "nothing was rewritten.")
        source = fm.path_on_disk(LOCAL, path)
        job["disk_path"] = source
        folder, name = fm.split_path(LOCAL, path)
        out_name = core.output_name(name)
        out_path = fm.join_path(LOCAL, folder, out_name) if folder else out_name
        if self._printing_file(out_path):
            raise core.PrintabilityError(f"{out_name} is being printed: {name} was not "
                                         "rewritten over it (rewrite it again after the print).")
        work = os.path.join(self._data(), "work")
        os.makedirs(work, exist_ok=True)
        tmp = os.path.join(work, f"{job['id']}.gcode")
        settings = self._current()
        before = _digest(source)
        self._progress(job, "planning the nozzle's angles")
        try:
            res = core.rewrite_file(source, tmp, settings, base_dir=self._data())
            if _digest(source) != before:  # never expected: the rewrite only reads it
                raise core.PrintabilityError(f"{name} changed while it was being rewritten; "
                                             "try again.")
            if res.already_processed:
                job["state"] = "skipped"
                self._mark_source(job, {"status": "skipped"})
                self._notify("info", f"printability: {name}",
                             f"{name} was already rewritten by printability; left as it is.",
                             extra={"job": job["id"], "path": path})
                return
            self._progress(job, "adding the rewritten file")
            summary = core.summary_of(res, source=path, output=out_path, settings=settings)
            fm.add_file(LOCAL, out_path, DiskFileWrapper(out_name, tmp, move=True),
                        allow_overwrite=True, display=out_name)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        fm.set_additional_metadata(LOCAL, out_path, META_KEY, summary, overwrite=True)
        self._mark_source(job, {"status": "done", "output": out_path})
        job.update(state="done", output=out_path)
        with self._jobs_lock:
            job["summary"] = summary
        t_in, t_out = summary["print_time_in"], summary["print_time_out"]
        times = (f"; print time {_duration(t_in)} as sliced, {_duration(t_out)} rewritten"
                 if t_in and t_out is not None else "")
        self._notify("success", f"printability: {out_name}",
                     f"{name} rewritten for {summary['nozzle']} on {summary['machine']}: "
                     f"{summary['rotary_words']} rotary words, {summary['lost_area']:.2f} mm² "
                     f"not printable ({100 * summary['lost_share']:.2f} %, "
                     f"{summary['dropped_moves']} moves dropped, {summary['split_moves']} "
                     f"shortened){times}.", extra={"job": job["id"], "path": path,
                                                    "output": out_path})

    def _run_report(self, job: dict[str, Any]) -> None:
        fm = self._file_manager
        path = job["path"]
        if not fm.file_exists(LOCAL, path):
            raise core.PrintabilityError(f"{job['name']} is not in OctoPrint's files.")
        source = fm.path_on_disk(LOCAL, path)
        job["disk_path"] = source
        out = os.path.join(self._data(), "reports", job["id"])
        self._progress(job, "analysing layers")
        try:
            core.write_report(source, out, self._current(), base_dir=self._data())
        except BaseException:
            shutil.rmtree(out, ignore_errors=True)
            raise
        url = f"plugin/{self._identifier}/report/{job['id']}/index.html"
        job.update(state="done", report=url)
        reports = os.path.join(self._data(), "reports")
        kept = sorted(os.listdir(reports), key=lambda d: os.path.getmtime(
            os.path.join(reports, d)))
        for old in kept[:-10]:  # the ten newest reports are kept
            shutil.rmtree(os.path.join(reports, old), ignore_errors=True)
        self._notify("success", f"printability: report for {job['name']}",
                     f"The analysis of {job['name']} is ready.",
                     extra={"job": job["id"], "path": path, "report": url})

    # ------------------------------------------------------------------ the axis check
    def on_gcode_received(self, comm, line: str, *args: Any, **kwargs: Any) -> str:
        """``octoprint.comm.protocol.gcode.received``: keep the M115 and M114 replies for
        the axis check; the line goes on unchanged."""
        try:
            with self._fw_lock:
                kind = self._fw.feed(line)
                waiting = self._axis["state"] == "checking"
            if kind == "m114" and waiting:
                self._axis_check_later(0.0)
        except Exception:
            self._logger.exception("printability: reading a reply failed")
        return line

    def _axis_check_later(self, delay: float) -> None:
        if self._axis_timer is not None:
            self._axis_timer.cancel()
        self._axis_timer = threading.Timer(delay, self._axis_check)
        self._axis_timer.daemon = True
        self._axis_timer.start()

    def _axis_check(self) -> None:
        if not self._printer.is_operational():
            return
        settings = self._current()
        try:
            letter = core.rotary_letter(settings, base_dir=self._data())
        except core.PrintabilityError as exc:
            letter, problem = None, str(exc)
        else:
            problem = None
        with self._fw_lock:
            report = core.FirmwareReport(list(self._fw.lines), self._fw.position)
        if letter is not None:
            source = (f"The rotary G-code printability writes for machine "
                      f"{settings.get('machine')}")
            problem = core.axis_problem(report, letter, self._port(), source)
        state = "ok" if problem is None else "missing"
        with self._fw_lock:
            changed = self._axis.get("message") != problem or self._axis["state"] != state
            self._axis = {"state": state, "message": problem, "letter": letter,
                          "firmware": report.lines[:1], "position": report.position}
        self._send({"type": "axis", **self._axis})
        if problem and changed:
            self._notify("error", "printability: no rotary axis", problem, kind="axis")

    def _check_job_axis(self, payload: dict[str, Any]) -> None:
        name = payload.get("name") or ""
        if not core.is_rotary_output(name):
            return
        with self._fw_lock:
            problem = self._axis.get("message") if self._axis["state"] == "missing" else None
        if problem:
            self._printer.cancel_print(tags={"trigger:plugin.printability.axis_check"})
            self._notify("error", f"printability: {name} cancelled", problem, kind="axis")

    # ------------------------------------------------------------------ OctoPrint 1.x / 2.x
    def _port(self) -> str:
        state = getattr(self._printer, "connection_state", None)  # 2.0: the parameters
        if isinstance(state, dict) and state.get("port"):
            return str(state["port"])
        try:
            _, port, _, _ = self._printer.get_current_connection()  # 1.x
        except Exception:
            port = None
        return str(port or "the printer's port")

    def _printing_file(self, path: str) -> bool:
        """Whether ``path`` (local storage) is the file being printed or paused."""
        if not (self._printer.is_printing() or self._printer.is_paused()):
            return False
        job = getattr(self._printer, "current_job", None)  # 2.0: a PrintJob
        if job is not None and hasattr(job, "path"):
            return job.path == path and getattr(job, "storage", LOCAL) == LOCAL
        try:
            return bool(self._printer.is_current_file(path, False))  # 1.x: path in storage
        except Exception:
            return False

    # ------------------------------------------------------------------ API
    def is_api_protected(self) -> bool:
        """The API needs a logged-in user or an API key."""
        return True

    def get_api_commands(self) -> dict[str, list[str]]:
        """``check`` (settings, without saving), ``rewrite`` and ``report`` (a file)."""
        return {"check": [], "rewrite": ["path"], "report": ["path"]}

    def on_api_get(self, request):
        """``?path=FILE``: the summary of a rewrite (404 when there is none); otherwise the
        settings, the jobs, the last notifications, the axis check and the choices."""
        path = request.values.get("path")
        if path:
            summary = self._summary(path)
            if summary is None:
                return flask.make_response(flask.jsonify(
                    error=f"no printability summary for {path}"), 404)
            return flask.jsonify(summary)
        with self._jobs_lock:
            jobs = [{k: v for k, v in j.items() if k not in ("summary", "disk_path")}
                    for j in self._jobs.values()]
        with self._fw_lock:
            axis = dict(self._axis)
        return flask.jsonify(settings=self._current(), jobs=jobs, events=list(self._events),
                             axis=axis, machines=core.machine_choices(),
                             flavors=core.flavor_choices(),
                             upload_modes=list(core.UPLOAD_MODES.items()))

    def on_api_command(self, command: str, data: dict[str, Any]):
        """``check``: what the settings page shows as it is typed (200, refusals included);
        ``rewrite``, ``report``: queue a job on a local G-code file (202 with its id)."""
        from octoprint.access.permissions import Permissions

        if command == "check":
            # a check answers 200 either way: a refusal is its result, not a failed request
            out: dict[str, Any] = {"ok": True, "errors": {}}
            accepted, refused = core.check_settings(data, base_dir=self._data())
            out["values"] = accepted
            out["errors"] = refused
            out["ok"] = not refused
            if accepted.get("nozzle"):
                out["nozzle"] = core.nozzle_facts(accepted["nozzle"], base_dir=self._data())
            return flask.jsonify(out)
        if not Permissions.FILES_UPLOAD.can():
            return flask.make_response(flask.jsonify(error="insufficient rights"), 403)
        path = str(data.get("path") or "")
        if not self._file_manager.file_exists(LOCAL, path) or \
                not valid_file_type(path, type="gcode"):
            return flask.make_response(flask.jsonify(
                error=f"{path!r} is not a G-code file in OctoPrint's local files"), 404)
        if command == "rewrite":
            if core.is_rotary_output(os.path.basename(path)):
                return flask.make_response(flask.jsonify(
                    error=f"{path} is a file printability wrote"), 409)
            if not self._settings.get(["nozzle"]):
                return flask.make_response(flask.jsonify(
                    error="set the installed nozzle in the plugin's settings first"), 409)
        job = self.enqueue(command, path)
        return flask.make_response(flask.jsonify(job=job["id"]), 202)

    def _summary(self, path: str) -> dict[str, Any] | None:
        fm = self._file_manager
        if not fm.file_exists(LOCAL, path):
            return None
        meta = (fm.get_metadata(LOCAL, path) or {}).get(META_KEY)
        if not isinstance(meta, dict):
            return None
        if "layers" in meta:
            return meta
        out = meta.get("output")  # the original: its note points at the rewritten file
        if out and fm.file_exists(LOCAL, out):
            full = (fm.get_metadata(LOCAL, out) or {}).get(META_KEY)
            if isinstance(full, dict) and "layers" in full:
                return full
        return {"source": path, **meta}

    # ------------------------------------------------------------------ pages
    def is_blueprint_protected(self) -> bool:
        """The pages need a logged-in user or an API key."""
        return True

    def is_blueprint_csrf_protected(self) -> bool:
        """The pages take part in OctoPrint's CSRF protection (they are all GETs)."""
        return True

    @octoprint.plugin.BlueprintPlugin.route("/nozzle.svg", methods=["GET"])
    def nozzle_svg(self):
        """The drawing of ``?spec=`` (default: the installed nozzle); 400 with the parser's
        message for a bad SPEC."""
        spec = flask.request.values.get("spec") or self._settings.get(["nozzle"]) or ""
        try:
            svg = core.nozzle_svg(spec, base_dir=self._data())
        except core.PrintabilityError as exc:
            return flask.make_response(str(exc), 400, {"Content-Type": "text/plain"})
        return flask.Response(svg, mimetype="image/svg+xml",
                              headers={"Cache-Control": "private, max-age=3600"})

    @octoprint.plugin.BlueprintPlugin.route("/summary", methods=["GET"])
    def summary_page(self):
        """The summary of ``?path=`` as a page."""
        path = flask.request.values.get("path") or ""
        summary = self._summary(path)
        if summary is None or "layers" not in summary:
            return flask.make_response(f"no printability summary for {path}", 404,
                                       {"Content-Type": "text/plain"})
        return flask.Response(core.summary_html(summary), mimetype="text/html")

    @octoprint.plugin.BlueprintPlugin.route("/report/<job>/<path:name>", methods=["GET"])
    def report_file(self, job: str, name: str):
        """A file of the report a ``report`` job wrote."""
        if not job.isalnum():
            flask.abort(404)
        return flask.send_from_directory(os.path.join(self._data(), "reports", job), name)


def _digest(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _duration(seconds: float | None) -> str:
    return "?" if seconds is None else core.format_duration(seconds)


__plugin_name__ = "printability"
__plugin_description__ = ("Rewrites uploaded G-code for an asymmetric nozzle on a rotary axis "
                          "(printability postprocess), with the nozzle's drawing, what could "
                          "not be printed and the print time before and after.")
__plugin_license__ = "GPLv3+"
__plugin_pythoncompat__ = ">=3.10,<4"
__plugin_implementation__ = PrintabilityPlugin()
__plugin_hooks__ = {
    "octoprint.comm.protocol.gcode.received": __plugin_implementation__.on_gcode_received,
}
