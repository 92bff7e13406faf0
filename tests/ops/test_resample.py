import pytest
import torch

from cosemdepth.ops import Conv2dSame, resize_bl1, resize_bl2, resize_nn1, resize_nn2, same_padding


def row(values):
    return torch.tensor(values, dtype=torch.float32).view(1, 1, 1, -1)


def test_bl1_doubling_matches_tf_legacy_rule():
    # design 3.1: [0,10,20,30] -> [0,5,10,15,20,25,30,30]
    out = resize_bl1(row([0, 10, 20, 30]), (1, 8))
    assert out.flatten().tolist() == [0, 5, 10, 15, 20, 25, 30, 30]


def test_bl1_general_ratio_against_formula():
    n_in, n_out = 5, 9  # x = k * 5/9
    x = torch.arange(n_in, dtype=torch.float32) ** 2
    out = resize_bl1(x.view(1, 1, 1, -1), (1, n_out)).flatten()
    for k in range(n_out):
        src = k * n_in / n_out
        k0 = int(src)
        k1 = min(k0 + 1, n_in - 1)
        a = src - k0
        assert out[k].item() == pytest.approx((1 - a) * x[k0].item() + a * x[k1].item(), rel=1e-6)


def test_bl1_is_separable_2d():
    x = torch.arange(12.0).view(1, 1, 3, 4)
    both = resize_bl1(x, (6, 8))
    rows_first = resize_bl1(resize_bl1(x, (3, 8)), (6, 8))
    torch.testing.assert_close(both, rows_first)
    assert both[0, 0, 0, 1].item() == 0.5 and both[0, 0, 1, 0].item() == 2.0


def test_bl2_downsampling_means():
    x = row(list(range(16)))
    assert resize_bl2(x, (1, 8)).flatten().tolist() == [0.5 + 2 * i for i in range(8)]  # pairwise means
    assert resize_bl2(x, (1, 4)).flatten().tolist() == [1.5, 5.5, 9.5, 13.5]  # means of (4m+1, 4m+2)


def test_nearest_rules():
    x = row(list(range(16)))
    assert resize_nn2(x, (1, 8)).flatten().tolist() == [1, 3, 5, 7, 9, 11, 13, 15]
    assert resize_nn2(x, (1, 4)).flatten().tolist() == [2, 6, 10, 14]
    assert resize_nn1(x, (1, 4)).flatten().tolist() == [0, 4, 8, 12]
    # x2 upsampling: both are pixel replication, also on integer tensors
    lab = torch.tensor([[1, 2], [3, 4]]).view(1, 1, 2, 2)
    for fn in (resize_nn1, resize_nn2):
        assert fn(lab, (4, 4))[0, 0].tolist() == [[1, 1, 2, 2], [1, 1, 2, 2], [3, 3, 4, 4], [3, 3, 4, 4]]
    # non-integer upsampling 3 -> 5: NN1 floor(k*0.6) = 0,0,1,1,2; NN2 floor((k+.5)*0.6) = 0,0,1,2,2
    x3 = row([10, 20, 30])
    assert resize_nn1(x3, (1, 5)).flatten().tolist() == [10, 10, 20, 20, 30]
    assert resize_nn2(x3, (1, 5)).flatten().tolist() == [10, 10, 20, 30, 30]


def test_opencv_nearest_1024_to_384_indices():
    x = torch.arange(1024).view(1, 1, 1, -1)
    out = resize_nn1(x, (1, 384)).flatten()
    assert out.tolist() == [(k * 1024) // 384 for k in range(384)]


@pytest.mark.parametrize("n, before, after", [(384, 0, 1), (192, 0, 1), (45, 1, 1), (7, 1, 1), (2, 0, 1)])
def test_same_padding_stride2(n, before, after):
    assert same_padding(n, 3, 2) == (before, after)
    assert same_padding(n, 3, 1) == (1, 1)


def test_conv2d_same_stride2_pads_bottom_right():
    torch.manual_seed(0)
    conv = Conv2dSame(2, 3, 3, stride=2)
    x = torch.randn(1, 2, 6, 8)
    ref = torch.nn.functional.conv2d(torch.nn.functional.pad(x, (0, 1, 0, 1)), conv.weight, conv.bias, stride=2)
    torch.testing.assert_close(conv(x), ref)
    assert conv(torch.randn(1, 2, 7, 9)).shape[-2:] == (4, 5)  # ceil
