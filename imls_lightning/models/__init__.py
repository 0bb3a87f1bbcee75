"""Networks of imls-lightning (plain ``nn.Module``s; the LightningModules live in ``tasks/``)."""
from imls_lightning.models.enhancenet import EnhanceNet
from imls_lightning.models.fovolnet import FoVolNet
from imls_lightning.models.iml import IMLNet, IMLOutput, IMLRecNN, c_share, ipr
from imls_lightning.models.ims import IMSDiscriminator, IMSGenerator, im_to_target, output_to_im
from imls_lightning.models.unet import UNet

__all__ = [
    "UNet",
    "EnhanceNet",
    "FoVolNet",
    "IMLNet",
    "IMLOutput",
    "IMLRecNN",
    "ipr",
    "c_share",
    "IMSGenerator",
    "IMSDiscriminator",
    "im_to_target",
    "output_to_im",
]
