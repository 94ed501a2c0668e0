"""zipon's framework: config, artifact stores, manifests, the runner, geometry conventions, readers, the CLI."""

__version__ = "0.1.0"
