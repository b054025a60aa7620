import pytest
import torch as th

from sb3_ef.ef.decoder import FrameDecoder, decoder_layers


@pytest.mark.parametrize("size", [8, 32, 64, 84])
def test_decodes_to_frame_size_in_unit_range(size):
    decoder = FrameDecoder(20, (3, size, size), channels=8)
    frames = decoder(th.randn(2, 20))
    assert frames.shape == (2, 3, size, size)
    assert frames.min() >= 0 and frames.max() <= 1


def test_84_follows_the_authors_stack():
    decoder = FrameDecoder(2048, (3, 84, 84))
    convs = [block[0] for block in decoder.blocks]
    assert [(c.in_channels, c.out_channels) for c in convs] == [(2048, 64), (64, 64), (64, 64), (64, 64), (64, 3)]
    assert decoder.input_sizes == [1, 5, 10, 21, 42]
    assert all(c.bias is None for c in convs)
    assert isinstance(decoder.blocks[-1][-1], th.nn.Sigmoid)
    assert abs(float(convs[0].weight.detach().std()) - 0.02) < 0.002


def test_64_doubles_from_4():
    assert decoder_layers(64) == ((4, 1, 0), (4, 2, 1), (4, 2, 1), (4, 2, 1), (4, 2, 1))
    assert FrameDecoder(8, (3, 64, 64), channels=4).input_sizes == [1, 4, 8, 16, 32]


@pytest.mark.parametrize("size", [4, 48, 100])
def test_unsupported_size_is_rejected(size):
    with pytest.raises(ValueError, match=f"Unsupported frame size {size}"):
        FrameDecoder(8, (3, size, size))


def test_non_square_frame_is_rejected():
    with pytest.raises(ValueError, match="square"):
        FrameDecoder(8, (3, 64, 32))


def test_skip_map_is_used_and_required():
    decoder = FrameDecoder(16, (3, 32, 32), channels=8, skip_channels=5)
    features = th.randn(2, 16)
    skip = th.randn(2, 5, 15, 15, requires_grad=True)
    decoder(features, skip).sum().backward()
    assert skip.grad is not None and skip.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="pass a skip"):
        decoder(features)
    with pytest.raises(ValueError, match=r"\(2, 5, h, w\)"):
        decoder(features, th.randn(2, 4, 15, 15))
    with pytest.raises(ValueError, match="do not pass"):
        FrameDecoder(16, (3, 32, 32), channels=8)(features, skip)
