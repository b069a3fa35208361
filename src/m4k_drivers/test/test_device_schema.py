"""Device backends' fields as schema Fields: the docs' source and the validator's."""

from m4k_drivers import config as dconfig
from m4k_drivers import registry


def test_every_backend_field_is_a_documented_schema_field_whose_default_validates():
    sections = dconfig.schema_sections()
    # Not every section is a backend's: kernel_standin (the driver host's own switch) is
    # one too, and its fields are held to the same documentation and default checks below.
    pairs = {(s.path, s.title.split('backend: ')[1].split(' ')[0])
             for s in sections if 'backend: ' in s.title}
    assert [s.path for s in sections if 'backend: ' not in s.title] == ['kernel_standin']
    for kind in registry.kinds():
        for backend in registry.backends(kind):
            assert ('devices.' + kind, backend) in pairs
    for sec in sections:
        for name, field in sec.fields.items():
            assert field.description, (sec.title, name)
            # a placeholder names where the default comes from: the port labelled with the
            # kind, a setting of the layered configuration (Derived; its value is checked in
            # test_registry_config)
            if not field.required and name != 'xddp_port' and not field.derived_from:
                assert field.problem(field.default) is None, (sec.title, name)


def test_param_as_field_keeps_the_drivers_messages():
    p = registry.Param((int, str), 1, 'bus', lambda v: 'must be small' if v == 99 else None)
    f = p.as_field()
    assert f.type == 'int|str' and f.default == 1 and f.description == 'bus'
    assert f.problem(1.5) == 'expected int or str, got 1.5'
    assert f.problem(99) == 'must be small, got 99'
    assert registry.Param(str).as_field().required
    assert registry.Param((float, type(None)), None).as_field().validate('x', 2) == 2.0
