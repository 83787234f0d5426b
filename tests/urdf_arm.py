"""A small URDF arm the tests share (not a test module: imported by test_dataset and test_recordings)."""

# A 3-joint arm: shoulder yaw, elbow pitch, wrist spin, plus a fixed tool frame. The non-ASCII comment
# checks that the URDF text survives the round trip byte for byte.
URDF_3_JOINTS = """<?xml version="1.0"?>
<robot name="tri_arm">
  <!-- test arm, déjà vu -->
  <link name="base_link"/>
  <link name="upper_arm"/>
  <link name="forearm"/>
  <link name="wrist_link"/>
  <link name="tool0"/>
  <joint name="shoulder" type="revolute">
    <parent link="base_link"/><child link="upper_arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3.0" upper="3.0" effort="10" velocity="1"/>
  </joint>
  <joint name="elbow" type="revolute">
    <parent link="upper_arm"/><child link="forearm"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="2.0" effort="10" velocity="1"/>
  </joint>
  <joint name="wrist" type="revolute">
    <parent link="forearm"/><child link="wrist_link"/>
    <origin xyz="0 0 0.25" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3.1" upper="3.1" effort="10" velocity="1"/>
  </joint>
  <joint name="tool_joint" type="fixed">
    <parent link="wrist_link"/><child link="tool0"/>
    <origin xyz="0 0 0.05" rpy="0 0 0"/>
  </joint>
</robot>
"""
