# lightfarm for Blender: import a bake, or send the open scene to a
# lightfarmd and import what it bakes (README "Into Blender"). Install:
# Edit > Preferences > Add-ons > Install, the zip of this folder (or link
# the folder into Blender's scripts/addons). The work is in bake_import.py
# and service.py, which a script can call without the user interface
# (tests/blender/import_bake.py does).
import os
import tempfile
import threading

import bpy
from bpy.props import IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from . import bake_import, service

bl_info = {
    "name": "lightfarm",
    "author": "lightfarm",
    "version": (1, 0, 0),
    "blender": (3, 4, 0),
    "location": "File > Import > lightfarm bake; View3D > Sidebar > lightfarm",
    "description": "Import lightfarm bakes (the lightmap on each material) and bake the open scene on a lightfarmd",
    "category": "Import-Export",
}


def bake_open_scene(url, token, folder, spec=None, on_status=None):
    """Exports the open scene as a glb, bakes it on the lightfarmd at `url`,
    downloads the result into `folder` and imports it. Returns the job id.
    Blocks until the job ends (the operator below runs the waiting in a
    thread)."""
    job = send_open_scene(url, token, spec)
    receive_bake(url, token, job, folder, on_status)
    bake_import.import_bake(folder)
    return job


def send_open_scene(url, token, spec=None):
    """The open scene, exported as a glb and submitted: the job's id."""
    bake_import._numpy_bool_alias()
    with tempfile.TemporaryDirectory(prefix="lightfarm-") as tmp:
        name = bpy.path.display_name_from_filepath(bpy.data.filepath) or "untitled"
        glb = os.path.join(tmp, name + ".glb")
        result = bpy.ops.export_scene.gltf(filepath=glb, export_format="GLB", export_lights=True, export_apply=True)
        if "FINISHED" not in result:
            raise service.ServiceError("Blender's glTF exporter failed")
        server = service.Lightfarmd(url, token)
        return server.submit(server.upload_glb(glb), spec)


def receive_bake(url, token, job, folder, on_status=None):
    server = service.Lightfarmd(url, token)
    server.wait(job, on_status=on_status)
    server.fetch(job, folder)


class LightfarmPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    url: StringProperty(name="Server", default="http://127.0.0.1:8750")
    token: StringProperty(name="Token", subtype="PASSWORD")

    def draw(self, context):
        self.layout.prop(self, "url")
        self.layout.prop(self, "token")


class LIGHTFARM_OT_import_bake(bpy.types.Operator, ImportHelper):
    """Import a lightfarm bake folder: scene.lightmapped.glb with its lightmap on every material"""

    bl_idname = "lightfarm.import_bake"
    bl_label = "Import lightfarm bake"
    filename_ext = ".glb"
    filter_glob: StringProperty(default="scene.lightmapped.glb;manifest.json", options={"HIDDEN"})

    def execute(self, context):
        try:
            objects = bake_import.import_bake(os.path.dirname(self.filepath))
        except bake_import.BakeImportError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, "lightfarm: %d objects with their lightmap" % len(objects))
        return {"FINISHED"}


class LIGHTFARM_OT_bake_scene(bpy.types.Operator):
    """Send the open scene to the lightfarmd in the add-on's preferences and import the bake"""

    bl_idname = "lightfarm.bake_scene"
    bl_label = "Bake on lightfarm"
    passes: IntProperty(name="Passes", default=256, min=1)
    folder: StringProperty(name="Into", subtype="DIR_PATH", default="//lightfarm")

    def execute(self, context):
        prefs = context.preferences.addons[__name__].preferences
        self.url, self.token = prefs.url, prefs.token
        try:
            self.job = send_open_scene(self.url, self.token, {"outputs": {"lightmap": {"passes": self.passes}}})
        except service.ServiceError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.into = bpy.path.abspath(self.folder) if bpy.data.filepath else os.path.join(tempfile.gettempdir(), self.job)
        self.error, self.progress = None, "queued"
        self.thread = threading.Thread(target=self._wait, daemon=True)
        self.thread.start()
        self.timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _wait(self):
        def said(status):
            progress = status.get("progress", {})
            self.progress = "%s %d%%" % (status.get("state", ""), int(100 * progress.get("fraction", 0.0)))

        try:
            receive_bake(self.url, self.token, self.job, self.into, said)
        except service.ServiceError as e:
            self.error = str(e)

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        context.workspace.status_text_set("lightfarm job %s: %s" % (self.job[:12], self.progress))
        if self.thread.is_alive():
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self.timer)
        context.workspace.status_text_set(None)
        if self.error:
            self.report({"ERROR"}, self.error)
            return {"CANCELLED"}
        try:
            bake_import.import_bake(self.into)
        except bake_import.BakeImportError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, "lightfarm: job %s imported from %s" % (self.job, self.into))
        return {"FINISHED"}


class LIGHTFARM_PT_panel(bpy.types.Panel):
    bl_label = "lightfarm"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "lightfarm"

    def draw(self, context):
        self.layout.operator(LIGHTFARM_OT_bake_scene.bl_idname)
        self.layout.operator(LIGHTFARM_OT_import_bake.bl_idname)


def _menu_import(self, context):
    self.layout.operator(LIGHTFARM_OT_import_bake.bl_idname, text="lightfarm bake (scene.lightmapped.glb)")


_classes = (LightfarmPreferences, LIGHTFARM_OT_import_bake, LIGHTFARM_OT_bake_scene, LIGHTFARM_PT_panel)


def register():
    for cls in _classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
