"""raytrax: a differentiable Whitted-style raytracer in JAX."""

from .camera import Camera
from .integrator import RenderOptions, render
from .lights import PointLights
from .materials import Materials, fresnel_dielectric, refract
from .params import parameters, with_parameters
from .fit import FitResult, fit
from .scene import Environment, Scene, SceneBuilder, Settings
from .shapes import Boxes, Mesh, Planes, Quads, Spheres, Tetrahedra, Triangles
from .textures import Checker, ImageTexture, Stripes, builtin_image
from .scenefile import load_scene, save_scene, SceneError
from .imageio import save_image, load_image

__version__ = "0.1.0"
