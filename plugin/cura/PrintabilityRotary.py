# Cura PostProcessingPlugin script: a thin shim that runs ``printability postprocess``.
#
# Cura's bundled Python lacks numpy/shapely, so the work is done by the printability command
# installed in its own environment. Copy this file and printability_rotary.json into Cura's
# "scripts" folder (Help > Show Configuration Folder > scripts), restart Cura, then
# Extensions > Post Processing > Modify G-Code > Add a script > "printability: rotary nozzle".
#
# License: GPL-3.0-or-later (like Cura and printability).
"""Cura post-processing script calling ``printability postprocess``."""

import json
import os
import shlex
import subprocess
import tempfile

from ..Script import Script  # Cura's PostProcessingPlugin base class

_SETTINGS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "printability_rotary.json")


class PrintabilityRotary(Script):
    """Turn an asymmetric nozzle on a rotary axis so that it never prints outside the part."""

    def getSettingDataString(self):
        with open(_SETTINGS, encoding="utf-8") as fh:
            return json.dumps(json.load(fh))

    def command(self, path):
        """The command line run on the G-code file ``path``."""
        cmd = [self.getSettingValueByKey("executable") or "printability", "postprocess",
               "--nozzle", self.getSettingValueByKey("nozzle"),
               "--machine", self.getSettingValueByKey("machine")]
        cmd += shlex.split(self.getSettingValueByKey("extra") or "")
        return [*cmd, path]

    def execute(self, data):
        """Cura hands the G-code as a list of chunks (start, then one per layer) and takes the
        processed list back. On any failure Cura's G-code is returned unchanged and the reason
        is shown to the user, so nothing half-processed is ever printed."""
        fd, path = tempfile.mkstemp(suffix=".gcode", prefix="printability-cura-")
        try:
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                fh.write("".join(data))
            try:
                proc = subprocess.run(self.command(path), capture_output=True, text=True,
                                      timeout=int(self.getSettingValueByKey("timeout") or 1800))
            except (OSError, subprocess.SubprocessError) as exc:
                _report(f"cannot run {self.getSettingValueByKey('executable')!r}: {exc}")
                return data
            if proc.returncode != 0:
                _report(proc.stderr.strip() or proc.stdout.strip()
                        or f"printability postprocess failed (exit code {proc.returncode})")
                return data
            with open(path, encoding="utf-8", newline="") as fh:
                text = fh.read()
        finally:
            try:
                os.unlink(path)
            except OSError:
                pass
        return split_layers(text)


def _report(text):
    """Log and show a failure in Cura (printed when run outside Cura)."""
    try:
        from UM.Logger import Logger
        from UM.Message import Message
    except ImportError:  # outside Cura (tests)
        print("printability: " + text)
        return
    Logger.log("e", "printability: %s", text)
    Message(text, title="printability: G-code left unchanged").show()


def split_layers(text):
    """Cut G-code text back into Cura's chunks: a new chunk at every ';LAYER:' line."""
    chunks, current = [], []
    for line in text.splitlines(keepends=True):
        if line.startswith(";LAYER:") and current:
            chunks.append("".join(current))
            current = []
        current.append(line)
    if current:
        chunks.append("".join(current))
    return chunks
