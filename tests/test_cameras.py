import numpy as np
import pytest

from sgdr.cameras import Camera, CameraError


def test_look_at_projects_target_to_centre_and_up_to_top():
    cam = Camera.look_at([0, -3, 1], [0, 0, 1], [0, 0, 1], 60.0, 64, 48)
    uv, z = cam.project(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.5], [0.5, 0.0, 1.0]]))
    assert np.allclose(uv[0], [32, 24])
    assert z[0] == pytest.approx(3.0)
    assert uv[1, 1] < 24  # world up is image up (smaller v)
    assert uv[2, 0] > 32  # world +x is to the right when looking along +y
    # half the horizontal fov reaches the image border
    half = 3.0 * np.tan(np.radians(30.0))
    uv_edge, _ = cam.project(np.array([[half, 0.0, 1.0]]))
    assert uv_edge[0, 0] == pytest.approx(64.0)


def test_opengl_round_trip():
    cam = Camera.look_at([1.0, 2.0, 3.0], [0.2, 0.1, 0.3], [0, 0, 1], 45.0, 32, 32, "v0")
    back = Camera.from_c2w_opengl(cam.c2w_opengl, cam.K, 32, 32, "v0")
    assert np.allclose(back.w2c, cam.w2c)
    assert np.allclose(cam.centre, [1.0, 2.0, 3.0])
    # OpenGL camera looks down its -z axis
    gl_forward = -cam.c2w_opengl[:3, 2]
    assert np.allclose(gl_forward, cam.R[2])
    assert Camera.from_dict(cam.to_dict()).name == "v0"


def test_fov_round_trip():
    K = Camera.intrinsics_from_fov(50.0, 100, 80)
    cam = Camera(K, np.eye(3), np.zeros(3), 100, 80)
    assert cam.fov_x_deg == pytest.approx(50.0)


@pytest.mark.parametrize(
    "kwargs,field",
    [
        (dict(K=np.eye(2)), "K"),
        (dict(R=np.diag([1.0, 1.0, -1.0])), "R"),
        (dict(t=np.zeros(2)), "t"),
        (dict(width=0), "width"),
    ],
)
def test_bad_cameras_name_the_field(kwargs, field):
    base = dict(K=np.eye(3), R=np.eye(3), t=np.zeros(3), width=4, height=4, name="bad")
    base.update(kwargs)
    with pytest.raises(CameraError, match=field):
        Camera(**base)
