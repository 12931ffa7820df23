import pickle
import subprocess
import sys

import pytest
import torch
from torch.utils.data import DataLoader, Dataset
from torchvision import tv_tensors  # the [vision] extra, which [test] pulls in
from torchvision.transforms import v2

import torchfluidwarp
from torchfluidwarp.augment.transforms import RandomFluidWarp, fluid_warp

H, W = 64, 80


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _warp(seed=0, **kwargs):
    kwargs = {"strength": (0.3, 0.4), "radius": (14.0, 24.0), "steps": (6, 8), "grid": 16, **kwargs}
    return RandomFluidWarp(generator=torch.Generator().manual_seed(seed), **kwargs)


def _sample(seed=0):
    g = torch.Generator().manual_seed(seed)
    image = tv_tensors.Image((torch.rand(3, H, W, generator=g) * 255).to(torch.uint8))
    boxes = torch.tensor([[6, 8, 30, 40], [40, 20, 74, 58], [20, 36, 50, 60]])
    inside = boxes[:, None, :2] + 2 + torch.rand(3, 4, 2, generator=g) * (boxes[:, None, 2:] - boxes[:, None, :2] - 4)
    mask = torch.zeros(3, H, W, dtype=torch.uint8)
    for k, (x1, y1, x2, y2) in enumerate(boxes.tolist()):
        mask[k, y1:y2, x1:x2] = 1
    return {
        "image": image,
        "masks": tv_tensors.Mask(mask),
        "boxes": tv_tensors.BoundingBoxes(boxes, format="XYXY", canvas_size=(H, W)),
        "keypoints": tv_tensors.KeyPoints(inside.reshape(-1, 2) - 0.5, canvas_size=(H, W)),
        "label": 7,
        "name": "sample",
    }


def _inside(points, boxes):
    """points (N, M, 2) in pixel centres; boxes (N, 4) xyxy with pixel edges at integers."""
    p = points + 0.5
    return ((p >= boxes[:, None, :2]) & (p <= boxes[:, None, 2:])).all()


def test_compose_keeps_types_and_geometry():
    pipe = v2.Compose([v2.RandomHorizontalFlip(p=1), _warp(0), v2.ToDtype(torch.float32, scale=True)])
    sample = _sample()
    out = pipe(sample)
    assert type(out["image"]) is tv_tensors.Image and out["image"].dtype == torch.float32
    assert out["image"].shape == (3, H, W) and 0 <= out["image"].min() and out["image"].max() <= 1
    assert type(out["masks"]) is tv_tensors.Mask and out["masks"].dtype == torch.uint8
    assert set(out["masks"].unique().tolist()) <= {0, 1}
    boxes, kp = out["boxes"], out["keypoints"]
    assert type(boxes) is tv_tensors.BoundingBoxes and boxes.format == tv_tensors.BoundingBoxFormat.XYXY
    assert boxes.canvas_size == (H, W) and boxes.dtype == torch.int64
    assert type(kp) is tv_tensors.KeyPoints and kp.canvas_size == (H, W)
    assert out["label"] == 7 and out["name"] == "sample"
    flipped = v2.RandomHorizontalFlip(p=1)(sample)
    assert (kp - flipped["keypoints"]).norm(dim=-1).max() > 1.0  # the warp did move things
    assert _inside(kp.view(3, 4, 2), boxes)
    # each mask moved with its box: the carried mask lies within the carried box
    for k, (x1, y1, x2, y2) in enumerate(boxes.tolist()):
        ys, xs = out["masks"][k].nonzero(as_tuple=True)
        assert xs.min() >= x1 and xs.max() < x2 and ys.min() >= y1 and ys.max() < y2


def test_one_draw_serves_all_inputs_of_a_call():
    image = tv_tensors.Image(torch.rand(3, H, W, generator=torch.Generator().manual_seed(1)))
    a, b = _warp(3)(image, image.clone())
    assert torch.equal(a, b)
    assert torch.equal(a, _warp(3)(image))


@pytest.mark.parametrize("fmt", ["XYWH", "CXCYWH"])
def test_any_box_format_matches_the_xyxy_result(fmt):
    boxes = tv_tensors.BoundingBoxes(
        [[6.0, 8.0, 30.0, 40.0], [40.0, 20.0, 74.0, 58.0]], format="XYXY", canvas_size=(H, W)
    )
    other = v2.ConvertBoundingBoxFormat(fmt)(boxes)
    image = tv_tensors.Image(torch.zeros(1, H, W))
    _, ref = _warp(2)(image, boxes)
    _, out = _warp(2)(image, other)
    assert out.format == tv_tensors.BoundingBoxFormat[fmt] and out.canvas_size == (H, W)
    torch.testing.assert_close(v2.ConvertBoundingBoxFormat("XYXY")(out), ref, atol=1e-4, rtol=0)


def test_rotated_boxes_keep_their_angle_and_hold_their_points():
    box = torch.tensor([[40.0, 32.0, 30.0, 16.0, 30.0]])  # CXCYWHR, degrees
    rot = tv_tensors.BoundingBoxes(box, format="CXCYWHR", canvas_size=(H, W))
    corners = v2.ConvertBoundingBoxFormat("XYXYXYXY")(rot).view(4, 2)
    w = torch.rand(20, 4, generator=torch.Generator().manual_seed(0))
    pts = (w / w.sum(1, keepdim=True)) @ corners  # convex combinations: inside the box
    out_box, out_pts = _warp(5)(rot, tv_tensors.KeyPoints(pts - 0.5, canvas_size=(H, W)))
    assert out_box.format == tv_tensors.BoundingBoxFormat.CXCYWHR and out_box.canvas_size == (H, W)
    assert out_box[0, 4].item() == pytest.approx(30.0, abs=1e-3)
    c = v2.ConvertBoundingBoxFormat("XYXYXYXY")(out_box).view(4, 2)
    a, b = c[1] - c[0], c[3] - c[0]
    q = out_pts + 0.5 - c[0]
    s, t = (q @ a) / (a @ a), (q @ b) / (b @ b)
    assert ((s >= -1e-4) & (s <= 1 + 1e-4) & (t >= -1e-4) & (t <= 1 + 1e-4)).all()


def test_plain_tensors_pil_and_video():
    img = torch.rand(3, H, W)
    assert _warp(0)(img).shape == img.shape  # a lone plain tensor is the image
    video = tv_tensors.Video(torch.rand(2, 3, H, W))
    out = _warp(0)(video)
    assert type(out) is tv_tensors.Video and out.shape == video.shape
    pil = v2.ToPILImage()(img)
    assert _warp(0)(pil).size == pil.size


def test_unknown_types_pass_through():
    params = _warp(0).sampler.make_params(1, (H, W))
    other = torch.rand(4)
    assert fluid_warp("text", params) == "text" and fluid_warp(3, params) == 3
    out = _warp(0)({"image": tv_tensors.Image(torch.rand(3, H, W)), "aux": other})
    assert out["aux"] is other


class _Shapes(Dataset):
    def __init__(self, n, transform):
        self.n, self.transform = n, transform

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        return self.transform(_sample(0))  # the same sample each time: only the warp differs


def test_pickles_and_runs_in_a_dataloader_with_two_workers():
    t = v2.Compose([_warp(11), v2.ToDtype(torch.float32, scale=True)])
    pickle.loads(pickle.dumps(t))
    loader = DataLoader(_Shapes(4, t), batch_size=1, num_workers=2, collate_fn=lambda batch: batch[0])
    items = list(loader)
    assert len(items) == 4
    for item in items:
        assert type(item["image"]) is tv_tensors.Image and item["boxes"].canvas_size == (H, W)
        assert _inside(item["keypoints"].view(3, 4, 2), item["boxes"])
    # items 0 and 1 come from different workers: the generator was re-seeded in each
    assert not torch.equal(items[0]["image"], items[1]["image"])


@pytest.mark.slow  # a fresh interpreter imports torch: about 10 s on 2 busy cores
def test_torchvision_is_imported_only_when_asked_for():
    code = (
        "import sys, torchfluidwarp as t, torchfluidwarp.augment.tensor; "
        "assert not {'torchvision', 'starlette', 'uvicorn'} & set(sys.modules), sorted(sys.modules); "
        "t.RandomFluidWarp; assert 'torchvision' in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert torchfluidwarp.RandomFluidWarp is RandomFluidWarp


def test_plain_tensors_of_any_rank_and_dtype_are_images():
    img = (torch.rand(2, 3, H, W) * 255).to(torch.uint8)
    out = _warp(0)(img)
    assert type(out) is torch.Tensor and out.shape == img.shape and out.dtype == torch.uint8
    # a batch in one call is one sample: every image moves with the same warp
    twin = _warp(0)(img[:1].expand(2, -1, -1, -1).contiguous())
    assert torch.equal(twin[0], twin[1])


def _corrupt(x, bad):
    data = x.as_subclass(torch.Tensor).clone().float()
    data.view(-1)[data.numel() // 2] = bad
    return tv_tensors.wrap(data, like=x)


BAD = {"nan": float("nan"), "inf": float("inf"), "-inf": float("-inf")}
KINDS = {
    "masks": r"mask \(tv_tensors\.Mask\)",
    "boxes": r"boxes \(tv_tensors\.BoundingBoxes\)",
    "keypoints": r"keypoints \(tv_tensors\.KeyPoints\)",
    "image": r"\bimage\b",
}


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("key", KINDS)
def test_non_finite_input_is_refused_naming_its_kind(key, bad):
    sample = _sample(0)
    sample[key] = _corrupt(sample[key], BAD[bad])
    with pytest.raises(ValueError, match=KINDS[key]) as err:
        _warp(0)(sample)
    if key != "image":
        assert "image" not in str(err.value)


@pytest.mark.parametrize("bad", BAD)
def test_a_non_finite_video_is_refused_naming_it(bad):
    video = _corrupt(tv_tensors.Video(torch.rand(2, 3, H, W)), BAD[bad])
    with pytest.raises(ValueError, match=r"video \(tv_tensors\.Video\)"):
        _warp(0)(video)


def test_a_mask_with_no_objects_comes_back_empty():
    sample = _sample(0)
    sample["masks"] = tv_tensors.Mask(torch.zeros(0, H, W, dtype=torch.uint8))
    out = _warp(0)(sample)
    assert type(out["masks"]) is tv_tensors.Mask and out["masks"].shape == (0, H, W)
