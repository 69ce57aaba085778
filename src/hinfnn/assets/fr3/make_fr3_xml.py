# Writes src/hinfnn/assets/fr3/fr3.xml from src/hinfnn/assets/fr3/fr3.urdf (the recipe in assets/fr3/README.md).
import mujoco
from hinfnn.plant.mujoco.scene import _to_xml

ARMATURE = [0.2, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1]  # kg m^2: reflected motor inertia (see README.md)
urdf = open("src/hinfnn/assets/fr3/fr3.urdf").read().replace(
    '<robot name="fr3">',
    '<robot name="fr3">\n  <mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="true"/></mujoco>', 1)
spec = mujoco.MjSpec.from_string(urdf)
for j, a in zip(spec.joints, ARMATURE):
    j.armature = a
    j.frictionloss = 0.0  # the URDF's 0.2 N m of joint friction: not carried over (README.md)
spec.body("link8").add_site(name="flange", pos=[0.0, 0.0, 0.0], size=[0.005, 0.0, 0.0])
spec.compile()
xml = _to_xml(mujoco, spec)
head = ("<!-- The Franka Research 3 arm of src/hinfnn/assets/fr3/fr3.urdf (franka_description, Apache-2.0: see LICENSE\n"
        "     beside this file) read by MuJoCo's URDF compiler (fusestatic=false, discardvisual=true,\n"
        "     balanceinertia=true), the joints given an armature (0.2 kg m^2 on joints 1-4, 0.1 on 5-7), and the site \"flange\" added at\n"
        "     link8 (README.md). The URDF's joint damping (0.003 N m s/rad) is kept, its joint friction\n"
        "     (0.2 N m) is not (frictionloss 0). -->\n")
xml = xml.replace('<mujoco model="fr3">\n', '<mujoco model="fr3">\n' + head, 1)
open("src/hinfnn/assets/fr3/fr3.xml", "w").write(xml)
print(xml[:3000])
