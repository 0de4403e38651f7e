// The parts of three.js the workbench's 3D view (static/model3d.js) uses, bundled into one ES
// module, static/vendor/three.bundle.js, by `npm ci && npm run build` (three.js: MIT licence,
// its notice kept at the end of the bundle).
export {
  AmbientLight,
  Box3,
  BufferAttribute,
  BufferGeometry,
  Color,
  DirectionalLight,
  Mesh,
  MeshBasicMaterial,
  MeshPhongMaterial,
  PerspectiveCamera,
  Raycaster,
  Scene,
  SphereGeometry,
  Vector2,
  Vector3,
  WebGLRenderer,
} from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
