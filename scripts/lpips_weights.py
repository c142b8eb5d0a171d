"""Convert LPIPS weights for Prism: the `lpips` package's calibrated linear layers (v0.1) and
torchvision's ImageNet trunk (AlexNet or VGG-16) into one safetensors file that
`prism recon --lpips-weights FILE` reads (format `prism-lpips/1`, see
crates/recon/src/evaluate/lpips.rs).

Prism never downloads at run time. Run this once where torchvision can fetch its trunk weights
(or give a local torchvision state dict with --trunk):

    pip install torch torchvision lpips safetensors
    python scripts/lpips_weights.py --net alex -o lpips-alex.safetensors
    python scripts/lpips_weights.py --net alex --trunk alexnet-owt-7be5be79.pth -o lpips-alex.safetensors

Licences: the linear layers are the lpips package's (BSD-2-Clause), the trunks torchvision's
(BSD-3-Clause); keep their notices with files you redistribute.
"""

import argparse

import torch
import lpips
from safetensors.torch import save_file


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--net", choices=["alex", "vgg"], default="alex")
    ap.add_argument("--trunk", help="a local torchvision state dict of the trunk (offline use)")
    ap.add_argument("--random-trunk", action="store_true",
                    help="an untrained trunk (for testing the file format only)")
    ap.add_argument("-o", "--out", required=True)
    args = ap.parse_args()

    random_trunk = args.random_trunk or args.trunk is not None
    model = lpips.LPIPS(net=args.net, pretrained=True, pnet_rand=random_trunk, verbose=False).eval()
    if args.trunk:
        state = torch.load(args.trunk, map_location="cpu")
        features = {k[len("features."):]: v for k, v in state.items() if k.startswith("features.")}
        for s in range(1, 6):
            for idx, layer in getattr(model.net, "slice%d" % s).named_children():
                if isinstance(layer, torch.nn.Conv2d):
                    layer.weight.data = features[idx + ".weight"].float()
                    layer.bias.data = features[idx + ".bias"].float()

    tensors = {}
    for s in range(1, 6):
        for idx, layer in getattr(model.net, "slice%d" % s).named_children():
            if isinstance(layer, torch.nn.Conv2d):
                tensors["features.%s.weight" % idx] = layer.weight.detach().float().contiguous()
                tensors["features.%s.bias" % idx] = layer.bias.detach().float().contiguous()
    for k, lin in enumerate(model.lins):
        tensors["lin.%d.weight" % k] = lin.model[-1].weight.detach().float().contiguous()
    trunk = "random" if args.random_trunk else (args.trunk or "torchvision ImageNet")
    save_file(tensors, args.out, metadata={
        "format": "prism-lpips/1",
        "net": args.net,
        "lpips_version": "0.1",
        "trunk": trunk,
    })
    print("wrote %s (%s, trunk: %s, %d tensors)" % (args.out, args.net, trunk, len(tensors)))


if __name__ == "__main__":
    main()
