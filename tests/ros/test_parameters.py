"""The node's parameters come from one table (mps_ros.ros.parameters): the docs' table is it, the
package's YAML file sets each one, and a running node describes each one (type, range,
description) as ``ros2 param describe`` would show it."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from twin_probe import NodeProcess, ask, wait_until

from mps_ros.ros.parameters import BY_NAME, PARAMETERS, NodeSettings, ParameterError, markdown_table

ROOT = Path(__file__).resolve().parents[2]


def test_the_docs_table_is_the_parameters_table():
    text = (ROOT / "docs" / "ros.md").read_text()
    assert markdown_table() in text, "docs/ros.md: paste mps_ros.ros.parameters.markdown_table()"


def test_the_settings_record_has_a_field_of_its_type_for_each_parameter_in_order():
    import dataclasses

    fields = dataclasses.fields(NodeSettings)
    assert [f.name for f in fields] == [p.name for p in PARAMETERS]
    kinds = {"bool": "bool", "integer": "int", "double": "float", "string": "str"}
    for f, p in zip(fields, PARAMETERS, strict=True):
        want = "tuple[str, ...]" if p.kind == "string_array" else kinds[p.kind]
        assert f.type == want, (p.name, f.type, want)


def test_the_settings_record_is_checked_as_the_node_reads_it():
    s = NodeSettings.defaults(t_end=20, outputs=["clock", " clock", "joint_states"], recording=" r.mcap ")
    assert s.t_end == 20.0 and isinstance(s.t_end, float)
    assert s.outputs == ("clock", "joint_states") and s.recording == "r.mcap"
    for given, said in (
        ({"pacing": "fast"}, "parameter pacing: 'fast', expected one of 'realtime', 'as_fast_as_possible'"),
        ({"outputs": ["clocks"]}, "parameter outputs: unknown output 'clocks'"),
        ({"release_slice": 1e-5}, "parameter release_slice: 1e-05 must be 0"),
        ({"tend": 1.0}, "unknown parameter tend: expected one of "),
    ):
        with pytest.raises(ParameterError) as err:
            NodeSettings.defaults(**given)
        assert str(err.value).startswith(said), str(err.value)


def test_the_package_yaml_sets_every_parameter_to_its_default_but_the_step():
    yaml = pytest.importorskip("yaml")
    cfg = yaml.safe_load((ROOT / "config" / "press_twin.yaml").read_text())
    values = cfg["press_twin"]["ros__parameters"]
    # the scene is the command line's (commented out in the file)
    assert set(values) == set(BY_NAME) - {"scene"}
    differ = {
        n: v for n, v in values.items() if v != BY_NAME[n].default or type(v) is not type(BY_NAME[n].default)
    }
    assert differ == {"dt": 0.001}


def test_a_running_node_describes_each_parameter(ros, tmp_path):
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import DescribeParameters, GetParameters

    node = ros.create_node(f"describer_{id(tmp_path) % 100000}")
    params = dict(
        pacing="realtime", dt=0.001, t_end=600, recording="none", real_time_factor=1, outputs="[clock]"
    )
    try:
        with NodeProcess(tmp_path, params, name="described") as proc:
            describe = node.create_client(DescribeParameters, "/press_twin/describe_parameters")
            get = node.create_client(GetParameters, "/press_twin/get_parameters")
            wait_until(
                lambda: describe.service_is_ready() and get.service_is_ready(),
                60,
                "the node's parameter services",
                poll=0.05,
            )
            names = [p.name for p in PARAMETERS]

            def answer(client, request):
                # asked again every 5 s until answered (both requests only read): a node that
                # has not yet matched this client's reader drops its answer ("failed to send
                # response (timeout)", seen in a clean clone's run)
                def spin(fut, seconds):
                    ros.spin_until_future_complete(node, fut, timeout_sec=seconds)

                got, _ = ask(client, request, spin, 5.0, 12)
                assert got is not None, f"no answer from {client.srv_name} in 60 s"
                return got

            got = {d.name: d for d in answer(describe, DescribeParameters.Request(names=names)).descriptors}
            values = answer(get, GetParameters.Request(names=["t_end", "real_time_factor"])).values
            assert proc.alive(), proc.log()
    finally:
        node.destroy_node()
    assert list(got) == names
    for p in PARAMETERS:
        d = got[p.name]
        assert d.read_only and not d.dynamic_typing and d.description == p.description
    rtf = got["real_time_factor"]
    assert rtf.type == ParameterType.PARAMETER_DOUBLE
    assert (rtf.floating_point_range[0].from_value, rtf.floating_point_range[0].to_value) == (1e-3, 1e3)
    prio = got["realtime_priority"]
    assert (prio.integer_range[0].from_value, prio.integer_range[0].to_value) == (0, 99)
    assert got["outputs"].type == ParameterType.PARAMETER_STRING_ARRAY
    assert "'realtime'" in got["pacing"].additional_constraints
    # integers given for real numbers were taken as such
    assert [(v.type, v.double_value) for v in values] == [
        (ParameterType.PARAMETER_DOUBLE, 600.0),
        (ParameterType.PARAMETER_DOUBLE, 1.0),
    ]
