# Sending the open Blender scene to a lightfarmd and bringing the bake back,
# over its HTTP API (docs/service.md): upload the scene (POST /v1/scenes, a
# glb as the body), create a job (POST /v1/jobs), read its state until it
# ends (GET /v1/jobs/ID), download its final files (GET .../artifacts).
# Only the standard library: Blender's Python has no requests.
import json
import os
import time
import urllib.error
import urllib.parse
import urllib.request

FINAL_STATES = ("succeeded", "failed", "cancelled")


class ServiceError(Exception):
    """What the server said (or why it could not be asked), one line."""


class Lightfarmd:
    def __init__(self, url, token, timeout=60.0):
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout

    def _call(self, method, route, body=None, content_type=None, what=""):
        request = urllib.request.Request(self.url + route, data=body, method=method)
        request.add_header("Authorization", "Bearer " + self.token)
        if content_type:
            request.add_header("Content-Type", content_type)
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as answer:
                return answer.read()
        except urllib.error.HTTPError as e:
            detail = e.read().decode("utf-8", "replace")
            try:
                detail = json.loads(detail).get("error", detail)
            except ValueError:
                pass
            raise ServiceError("%s: %s (HTTP %d)" % (what or route, detail.strip(), e.code)) from None
        except (urllib.error.URLError, OSError) as e:
            raise ServiceError("%s: cannot reach %s (%s)" % (what or route, self.url, e)) from None

    def _json(self, method, route, body=None, content_type=None, what=""):
        return json.loads(self._call(method, route, body, content_type, what))

    def upload_glb(self, glb_path):
        """Uploads a .glb; returns the scene's id."""
        with open(glb_path, "rb") as f:
            body = f.read()
        name = urllib.parse.quote(os.path.basename(glb_path))
        return self._json("POST", "/v1/scenes?name=" + name, body, "model/gltf-binary", "upload " + glb_path)["id"]

    def submit(self, scene_id, spec=None):
        """Creates a job of `scene_id` (spec: the job's other fields, docs/service.md); returns its id."""
        job = dict(spec or {"outputs": {"lightmap": {}}})
        job["scene"] = scene_id
        return self._json("POST", "/v1/jobs", json.dumps(job).encode(), "application/json", "create the job")["id"]

    def status(self, job):
        return self._json("GET", "/v1/jobs/" + job, what="read job " + job)

    def wait(self, job, poll_seconds=1.0, on_status=None):
        """Reads the job's state until it ends; returns its last status. Raises unless it succeeded."""
        while True:
            status = self.status(job)
            if on_status:
                on_status(status)
            if status.get("state") in FINAL_STATES:
                break
            time.sleep(poll_seconds)
        if status["state"] != "succeeded":
            raise ServiceError(
                "job %s %s: %s %s" % (job, status["state"], status.get("error", ""), status.get("cause", ""))
            )
        return status

    def fetch(self, job, folder):
        """Downloads the job's final files (no snapshots) into `folder`."""
        listing = self._json("GET", "/v1/jobs/%s/artifacts" % job, what="list the files of job " + job)
        os.makedirs(folder, exist_ok=True)
        names = [a["name"] for a in listing["artifacts"] if ".pass-" not in a["name"]]
        for name in names:
            data = self._call("GET", "/v1/jobs/%s/artifacts/%s" % (job, urllib.parse.quote(name)), what="fetch " + name)
            path = os.path.join(folder, name)
            with open(path + ".part", "wb") as f:
                f.write(data)
            os.replace(path + ".part", path)
        return names
