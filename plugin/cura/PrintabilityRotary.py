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
        return split_like(text, data)


def _report(text):
    """Log and show a failure in Cura (printed when run outside Cura)."""
    try:
        from UM.Logger import Logger
        from UM.Message import Message
    except ImportError:  # outside Cura (tests)
        print(text if text.startswith("printability") else "printability: " + text)
        return
    Logger.log("e", "printability: %s", text)
    Message(text, title="printability: G-code left unchanged").show()


def split_like(text, chunks):
    """Cut the processed text into Cura's chunks again, each starting where it started.

    Cura's list is its header, the start code, one chunk per layer (from its ';LAYER:' line)
    and the end code; scripts after ours (pause at height, timelapse) index it by layer. Each
    chunk's first line is found again in the processed text (its n-th occurrence, as in the
    original: printability keeps every line outside the part's extrusions byte for byte and
    only inserts lines), so the list keeps its length and boundaries. If a boundary cannot be
    found (a chunk that starts with a rewritten move), the text is cut at every ';LAYER:' line
    instead.
    """
    wanted = {}  # line -> [(occurrence, chunk index)]
    seen = {}
    for k, chunk in enumerate(chunks):
        lines = chunk.splitlines(keepends=True)
        if k and lines:
            wanted.setdefault(lines[0], []).append((seen.get(lines[0], 0), k))
        for line in lines:
            seen[line] = seen.get(line, 0) + 1
    if len(chunks) <= 1:
        return [text]
    starts, counts, pos = {}, {}, 0
    for line in text.splitlines(keepends=True):
        if line in wanted:
            n = counts.get(line, 0)
            for occurrence, k in wanted[line]:
                if occurrence == n:
                    starts[k] = pos
            counts[line] = n + 1
        pos += len(line)
    for k in range(len(chunks) - 1, 0, -1):  # an empty chunk stays empty, before the next
        if not chunks[k]:
            starts[k] = starts.get(k + 1, len(text))
    cuts = [starts.get(k) for k in range(1, len(chunks))]
    if None in cuts or cuts != sorted(cuts):
        return split_layers(text)
    bounds = [0, *cuts, len(text)]
    # (no itertools.pairwise: Cura 4's bundled Python is 3.8)
    return [text[bounds[i]:bounds[i + 1]] for i in range(len(bounds) - 1)]


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
