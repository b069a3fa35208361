"""docs/configuration.md is generated from the schema; the shipped files validate against it."""

import os

from wsenv import ROOT
import yaml

from m4k_bringup.configdoc import all_sections
from m4k_rt import schema

DOC = os.path.join(ROOT, 'docs', 'configuration.md')


def test_committed_configuration_doc_is_the_generated_one():
    with open(DOC, encoding='utf-8') as f:
        committed = f.read()
    generated = schema.markdown(all_sections())
    assert committed == generated, (
        'docs/configuration.md is stale: regenerate it with '
        '`config_doc --markdown > docs/configuration.md`')


def test_committed_bench_configuration_doc_is_the_generated_one():
    # The planner's parameters and the scenario files: m4k_bench sits above bringup, so its
    # settings have their own generated page.
    from m4k_bench import configdoc
    with open(os.path.join(ROOT, 'docs', 'bench-configuration.md'), encoding='utf-8') as f:
        committed = f.read()
    assert committed == configdoc.markdown(), (
        'docs/bench-configuration.md is stale: regenerate it with '
        '`python -m m4k_bench.configdoc --markdown > docs/bench-configuration.md`')


def test_every_field_is_documented_with_a_description():
    from m4k_bench import configdoc
    sections = all_sections() + configdoc.sections()
    titles = {s.title.split(' ')[0] for s in sections}
    assert {'runtime', 'tasks.<name>', 'ports', 'control', 'robot', 'm4k_bridge',
            'devices.motor,', 'devices.lrf,', 'world:', 'world.robot:', 'world.obstacles[]:',
            'world.events[]:', 'world.faults[]:', 'm4k_planner', 'commands[]:'} <= titles
    for sec in sections:
        for name, field in sec.fields.items():
            assert field.description.strip(), '{}.{}'.format(sec.path, name)


def test_shipped_control_and_robot_files_hold_only_schema_fields():
    # A key the schema does not know is refused by the loaders; the shipped files must pass.
    from m4k_rt.control.params import CONTROL
    for name, table in (('control', CONTROL), ('robot', schema.ROBOT)):
        with open(os.path.join(ROOT, 'config', name + '.yaml'), encoding='utf-8') as f:
            section = yaml.safe_load(f)[name]
        flat = schema.validate_tree(table, section, name)
        assert set(flat) == set(table), name
