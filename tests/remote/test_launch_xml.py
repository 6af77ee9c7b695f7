"""The XML a parent hands a child reads back, with our loader, as the same nodes."""

from __future__ import annotations

from launcher.remote.launch_xml import remote_launch_xml
from launcher.xml import load

LAUNCH = """<launch>
  <machine name="arm" address="10.1.2.3" env-loader="/e.sh"/>
  <group ns="robot">
    <node machine="arm" pkg="p" type="t" name="drv" args="a 'b c' &amp; &lt;x&gt;" respawn="true" respawn_delay="2.5"
          output="screen" cwd="node" launch-prefix="nice -n 5" required="false">
      <remap from="in" to="/scan"/>
      <env name="A" value="1 &quot;2&quot; &amp;"/>
    </node>
  </group>
</launch>
"""

FIELDS = ("package", "type", "name", "namespace", "args", "remap_args", "env_args", "respawn", "respawn_delay",
          "required", "output", "cwd", "launch_prefix")


def test_remote_xml_round_trips_every_field_but_the_machine(tmp_path):
    src = tmp_path / "a.launch"
    src.write_text(LAUNCH)
    (node,) = load([str(src)], [], environ={}).nodes
    out = tmp_path / "child.launch"
    out.write_text(remote_launch_xml([node]))
    (again,) = load([str(out)], [], environ={}).nodes
    assert again.machine_name is None
    assert [getattr(again, f) for f in FIELDS] == [getattr(node, f) for f in FIELDS]
