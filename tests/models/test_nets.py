"""stereojax.models.nets: the head's layer widths and the FLOP count of a network."""

import jax

from stereojax.models.nets import NetConfig, init_params, net_preset, network_flops


def test_downsize_head_widths():
    v = init_params(net_preset("downsize", 16), jax.random.PRNGKey(0))["params"]["head"]
    assert v["first_left"]["kernel"].shape == (16, 512)
    assert v["first_right"]["kernel"].shape == (16, 512)
    assert [v[f"dense{i}"]["kernel"].shape[1] for i in (1, 2, 3)] == [384, 256, 128]
    assert v["out"]["kernel"].shape == (128, 1)


def test_network_flops_by_hand():
    net = NetConfig(features=16, layers=4, widths=(64, 32))
    per_pixel = 2 * (9 * 16 + 3 * 9 * 16 * 16) + 2 * 16 * 64 + 16 * (64 * 32 + 32 * 1)
    assert network_flops(net, 10, 20, 16) == 2 * 200 * per_pixel
    paper = NetConfig()   # the paper's head: 512-384-256-128
    per_eval = 512 * 384 + 384 * 256 + 256 * 128 + 128
    assert network_flops(paper, 1, 1, 3) - network_flops(paper, 1, 1, 2) == 2 * per_eval
