"""data_gen: volumes, scenes, views, VTK rendering and the (view, image) cache."""
from data_gen.scenes import register_resolvers as _register_resolvers

# ``${imls_volumes_dir:}`` in conf/scene/*.yaml must resolve wherever a config is composed
_register_resolvers()
