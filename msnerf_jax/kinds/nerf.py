"""The "nerf" run kind: a radiance field of the photos (`msnerf nerf train`)."""

from msnerf_jax.core.config import NerfConfig
from msnerf_jax.kinds.base import RunKind
from msnerf_jax.models.nerf import NerfField, init_nerf_params

KIND = RunKind(
    name="nerf",
    config_class=NerfConfig,
    train_command="msnerf nerf train",
    title="NeRF",
    params_layout=('{"coarse": {"trunk", "rgb"}, "fine": {"trunk", "rgb"}} with the '
                   'hierarchical sampler; {"fine": {"trunk", "rgb"}, "occupancy": [G, G, G]} '
                   'with the grid sampler'),
    init_params=init_nerf_params,
    nerf_config=lambda config: config,
    field=NerfField,
)
