from taichi_sph.cli.main import entry

entry()
