"""``python -m imls_lightning.adaptive scene=NAME data=GROUP ims_checkpoint=<IMS .ckpt> ...`` (see :mod:`.cli`)."""
from imls_lightning.adaptive.cli import main

if __name__ == "__main__":
    main()
