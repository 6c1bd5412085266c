"""A spinning node with parameters and a service, for the remote `zenoh-robot param/service` tests.

Usage: svc_param_node.py --ns NS [-p name:=value ...]
"""
from __future__ import annotations

import argparse

from zenoh_robot import Node
from zenoh_robot.msgs import String
from zenoh_robot.parameters import SetParametersResult, add_param_argument, params_from_args

parser = argparse.ArgumentParser()
parser.add_argument("--ns", required=True)
add_param_argument(parser)
args = parser.parse_args()


def check(params):
    for p in params:
        if p.name == "gain" and p.value > 1.0:
            return SetParametersResult(False, "gain must be <= 1.0")
    return SetParametersResult(True)


with Node("pnode", namespace=args.ns, parameter_overrides=params_from_args(args)) as node:
    node.declare_parameter("depth", 10, "queue depth")
    node.declare_parameter("gain", 0.5)
    node.declare_parameter("mode", "fast")
    node.declare_parameter("frames", ["base", "cam"])
    node.add_on_set_parameters_callback(check)
    node.create_service("echo", String, String, lambda req: String(req.data.upper()))
    print("READY", flush=True)
    node.spin()
