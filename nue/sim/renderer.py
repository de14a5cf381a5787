"""RGB + metric z-depth rendering of a mesh with OpenGL through moderngl on EGL (no display needed).

On a CPU machine EGL gives Mesa's llvmpipe; on a GPU machine the vendor driver. Meshes are loaded
with trimesh: OBJ with textures, GLB, PLY with vertex colours, z-up or y-up. Surfaces are shaded
view-independently (texture or vertex colour x a fixed world-space light term), so a surface has
the same colour from every viewpoint. Depth is written by the fragment shader as the eye-space z
into a float32 attachment: exact metric z-depth, 0 where no surface lies within the far plane.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from nue.errors import SceneError
from nue.scene.scene import Scene, read_mesh
from nue.sim.camera import gl_projection_matrix, gl_view_matrix
from nue.sim.task import CameraConfig

_VERTEX_SHADER = """
#version 330
uniform mat4 u_view;
uniform mat4 u_proj;
in vec3 in_pos;
in vec2 in_uv;
in vec4 in_col;
out vec2 v_uv;
out vec4 v_col;
out vec3 v_world;
out float v_zdepth;
void main() {
    vec4 eye = u_view * vec4(in_pos, 1.0);
    gl_Position = u_proj * eye;
    v_uv = in_uv;
    v_col = in_col;
    v_world = in_pos;
    v_zdepth = -eye.z;
}
"""

_FRAGMENT_SHADER = """
#version 330
uniform sampler2D u_tex;
uniform bool u_use_tex;
uniform vec3 u_light;
in vec2 v_uv;
in vec4 v_col;
in vec3 v_world;
in float v_zdepth;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_depth;
void main() {
    vec3 n = normalize(cross(dFdx(v_world), dFdy(v_world)));
    float shade = 0.72 + 0.28 * abs(dot(n, u_light));
    vec4 base = u_use_tex ? texture(u_tex, v_uv) * v_col : v_col;
    f_color = vec4(base.rgb * shade, 1.0);
    f_depth = v_zdepth;
}
"""

_CONTEXT = None


def gl_context():
    """The process-wide standalone EGL context (created on first use)."""
    global _CONTEXT
    if _CONTEXT is None:
        import moderngl

        try:
            _CONTEXT = moderngl.create_standalone_context(backend="egl")
        except Exception as exc:
            raise RuntimeError(
                "cannot create an EGL OpenGL context; install libegl1 libegl-mesa0 libgl1-mesa-dri "
                f"(Debian) or a GPU driver with EGL ({type(exc).__name__}: {exc})"
            ) from None
    return _CONTEXT


def _material_image(material):
    """The colour texture of a trimesh material (SimpleMaterial or PBRMaterial), or None."""
    for attr in ("image", "baseColorTexture"):
        img = getattr(material, attr, None)
        if img is not None:
            return img
    return None


def _material_colour(material) -> np.ndarray:
    for attr in ("main_color", "baseColorFactor", "diffuse"):
        c = getattr(material, attr, None)
        if c is not None:
            c = np.asarray(c, dtype=np.float64).ravel()
            c = c / 255.0 if c.max() > 1.0 else c
            return np.concatenate([c[:3], [1.0]])
    return np.array([0.7, 0.7, 0.7, 1.0])


def mesh_draw_batches(scene_mesh, up_axis: str = "z"):
    """Flatten a trimesh Scene into draw batches ``(vertices (K, 9) float32, image | None)``.

    Each vertex row is (x, y, z, u, v, r, g, b, a), one row per triangle corner, z up.
    """
    batches = []
    for node in scene_mesh.graph.nodes_geometry:
        transform, geom_name = scene_mesh.graph[node]
        mesh = scene_mesh.geometry[geom_name]
        if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            continue
        verts = np.asarray(mesh.vertices, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]
        if up_axis == "y":
            verts = np.stack([verts[:, 0], -verts[:, 2], verts[:, 1]], axis=1)
        faces = np.asarray(mesh.faces)
        corners = faces.reshape(-1)
        n = len(corners)
        uv = np.zeros((n, 2))
        col = np.ones((n, 4))
        image = None
        visual = mesh.visual
        kind = getattr(visual, "kind", None)
        if kind == "texture":
            material = getattr(visual, "material", None)
            image = _material_image(material) if material is not None else None
            if image is not None and visual.uv is not None and len(visual.uv) == len(verts):
                uv = np.asarray(visual.uv, dtype=np.float64)[corners]
            else:
                image = None
                col[:] = _material_colour(material) if material is not None else col
        elif kind == "vertex":
            vc = np.asarray(visual.vertex_colors, dtype=np.float64) / 255.0
            col = vc[corners]
        elif kind == "face":
            fc = np.asarray(visual.face_colors, dtype=np.float64) / 255.0
            col = np.repeat(fc, 3, axis=0)
        else:
            col[:, :3] = 0.7
        data = np.concatenate([verts[corners], uv, col], axis=1).astype(np.float32)
        batches.append((data, image))
    return batches


class Renderer:
    """Renders RGB (H, W, 3) uint8 and z-depth (H, W) float32 metres of a mesh from a robot pose."""

    def __init__(self, scene, camera: CameraConfig = CameraConfig(), up_axis: str | None = None):
        """``scene``: a :class:`nue.scene.scene.Scene`, a mesh path, or a ``trimesh.Scene``/``Trimesh``."""
        import moderngl
        import trimesh

        self.camera = camera
        if isinstance(scene, Scene):
            up_axis = up_axis or scene.up_axis
            mesh = scene.load_mesh()
        elif isinstance(scene, (trimesh.Scene, trimesh.Trimesh)):
            mesh = scene if isinstance(scene, trimesh.Scene) else trimesh.Scene(scene)
        else:
            mesh = read_mesh(scene)
        self.up_axis = up_axis or "z"
        self.ctx = ctx = gl_context()
        self.program = ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self.program["u_light"].value = tuple(np.array([0.35, 0.55, 0.76]) / np.linalg.norm([0.35, 0.55, 0.76]))
        self.program["u_tex"].value = 0
        self._draws = []
        self._owned = [self.program]
        textures: dict[int, object] = {}
        for data, image in mesh_draw_batches(mesh, self.up_axis):
            vbo = ctx.buffer(data.tobytes())
            vao = ctx.vertex_array(self.program, [(vbo, "3f 2f 4f", "in_pos", "in_uv", "in_col")])
            tex = None
            if image is not None:
                key = id(image)
                if key not in textures:
                    img = image.convert("RGBA").transpose(Image.Transpose.FLIP_TOP_BOTTOM)  # OBJ: v = 0 is the image bottom
                    tex = ctx.texture(img.size, 4, img.tobytes())
                    tex.repeat_x = tex.repeat_y = True
                    tex.build_mipmaps()
                    tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                    textures[key] = tex
                    self._owned.append(tex)
                tex = textures[key]
            self._draws.append((vao, tex))
            self._owned += [vbo, vao]
        if not self._draws:
            raise SceneError(getattr(scene, "mesh_path", scene), "mesh has no triangles")
        size = (camera.width, camera.height)
        self._rb_color = ctx.renderbuffer(size, components=4)
        self._rb_depth = ctx.renderbuffer(size, components=1, dtype="f4")
        self._rb_z = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer(color_attachments=[self._rb_color, self._rb_depth], depth_attachment=self._rb_z)
        self._owned += [self._rb_color, self._rb_depth, self._rb_z, self.fbo]
        self.program["u_proj"].write(gl_projection_matrix(camera).T.astype("f4").tobytes())

    @property
    def n_triangles(self) -> int:
        return sum(vao.vertices // 3 for vao, _ in self._draws)

    def render(self, pose, floor_z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Render from robot pose ``(x, y, yaw)`` standing on a floor at height ``floor_z``.

        Returns ``rgb (H, W, 3) uint8`` and ``depth (H, W) float32`` (metric z-depth, 0 = nothing hit).
        """
        import moderngl

        ctx = self.ctx
        self.fbo.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        self.fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        self.program["u_view"].write(gl_view_matrix(pose, self.camera, floor_z).T.astype("f4").tobytes())
        for vao, tex in self._draws:
            if tex is not None:
                tex.use(0)
            self.program["u_use_tex"].value = tex is not None
            vao.render(moderngl.TRIANGLES)
        h, w = self.camera.height, self.camera.width
        rgb = np.frombuffer(self.fbo.read(components=3, attachment=0), dtype=np.uint8).reshape(h, w, 3)
        depth = np.frombuffer(self.fbo.read(components=1, attachment=1, dtype="f4"), dtype=np.float32)
        return np.ascontiguousarray(rgb[::-1]), np.ascontiguousarray(depth.reshape(h, w)[::-1])

    def release(self) -> None:
        """Free the GL objects of this renderer (the shared context stays)."""
        for obj in reversed(self._owned):
            obj.release()
        self._owned, self._draws = [], []
