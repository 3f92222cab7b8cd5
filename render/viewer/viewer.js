// The relightable viewer of `reflcap view` (render/viewer/viewer_page.h): shades a fit's mesh with
// the Lambert + Lafortune BRDF per atlas texel, in WebGL2 through three.js, at a held-out
// photograph's camera and light (shown beside it), or orbiting, with a movable light.
//
// The shader is the same model, in the same order, as the CPU reference renderer
// (render/reference/reference_renderer.cc, RenderImage's `shade`) and its BRDF twin
// (engine/brdf/lafortune.h, EvalChannel / LafortuneLobe; shaders/common for GLSL): the texel under
// the UV (TexelAtlas::PixelOfUv with kTexelTieOffset, then the 3x3 search of TexelUnderUv), its
// tangent frame re-orthogonalised against the interpolated normal, a lobe 0 where its base
// <= kPowBaseMin and saturated at kMaxLobeValue, black for back faces, unlit points and views
// below the shading normal. No cast shadows (the CPU reference traces them; this page does not).
// Cameras are pinholes without distortion: pixel (x, y) has its centre at integer coordinates
// (OpenCV), as the CPU renderer's rays.
'use strict';

(function () {
  const data = window.REFLCAP_DATA;

  function decodeFloats(base64) {
    const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
    return new Float32Array(bytes.buffer);
  }

  const vertexShader = `
    precision highp float;
    in vec3 position;
    in vec3 normal;
    in vec2 uv;
    uniform mat4 camFromObject;   // object frame -> OpenCV camera frame (x right, y down, z forward)
    uniform vec4 intrinsics;      // fx, fy, cx, cy (pixels)
    uniform vec2 imageSize;       // width, height (pixels)
    out vec3 vPos;
    out vec3 vNormal;
    out vec2 vUv;
    // Depth range of the clip volume, metres: far beyond any turntable object and camera.
    const float kNear = 0.001;
    const float kFar = 1000.0;
    void main() {
      vPos = position;
      vNormal = normal;
      vUv = uv;
      vec4 p = camFromObject * vec4(position, 1.0);
      float z = p.z;
      // Pixel u = fx x/z + cx has its centre at integer u; window x = u + 0.5; rows run down.
      float u = intrinsics.x * p.x + intrinsics.z * z;  // u * z
      float v = intrinsics.y * p.y + intrinsics.w * z;  // v * z
      float ndcX = 2.0 * (u + 0.5 * z) / imageSize.x - z;
      float ndcY = z - 2.0 * (v + 0.5 * z) / imageSize.y;
      float zClip = z * (kFar + kNear) / (kFar - kNear) - 2.0 * kFar * kNear / (kFar - kNear);
      gl_Position = vec4(ndcX, ndcY, zClip, z);
    }`;

  // The lobe sum, unrolled: GLSL ES indexes sampler arrays only with constants.
  function lobeSum(numLobes) {
    let code = '';
    for (let k = 0; k < numLobes; ++k) {
      code += `      f += LafortuneLobe(wiLocal, woLocal, texelFetch(lobeTex[${4 * k}], texel, 0).rgb,
                         texelFetch(lobeTex[${4 * k + 1}], texel, 0).rgb,
                         texelFetch(lobeTex[${4 * k + 2}], texel, 0).rgb,
                         texelFetch(lobeTex[${4 * k + 3}], texel, 0).rgb);\n`;
    }
    return code;
  }

  function fragmentShader(numLobes) {
    return `
    precision highp float;
    precision highp sampler2D;
    in vec3 vPos;
    in vec3 vNormal;
    in vec2 vUv;
    out vec4 outColor;
    uniform sampler2D rhoTex;      // rgb: rho_d, a: 1 where the atlas pixel is a texel
    uniform sampler2D tangentTex;  // xyz: the texel's tangent (TexelAtlas::tangent)
    uniform sampler2D lobeTex[${Math.max(1, 4 * numLobes)}];  // per lobe: Cx, Cy, Cz, n (rgb each)
    uniform ivec2 atlasSize;
    uniform vec3 cameraPos;        // object frame
    uniform int lightType;         // 0 point, 1 directional
    uniform vec3 lightPos;         // object frame (point)
    uniform vec3 lightDir;         // object frame, towards the light (directional)
    uniform vec3 intensity;
    uniform float exposure;
    uniform float displayScale;    // display: sRGB(clamp(exposure * radiance * displayScale))
    const float kTexelTieOffset = 1.0 / 300.0;  // TexelAtlas::PixelOfUv's tie shift
    const float kPowBaseMin = 1e-30;            // SafePow: a lobe base at or below is 0
    const float kMaxLobeValue = 1e30;           // LafortuneLobe's saturation
    const float kInvPi = 0.31830988618379067;

    bool isTexel(ivec2 p) { return texelFetch(rhoTex, p, 0).a > 0.5; }

    // TexelUnderUv: the atlas pixel under the UV, else the first texel of its 3x3 neighbourhood.
    bool texelOfHit(vec2 uv, out ivec2 texel) {
      float fx = floor(uv.x * float(atlasSize.x) + kTexelTieOffset);
      float fy = floor((1.0 - uv.y) * float(atlasSize.y) + kTexelTieOffset);
      ivec2 p = clamp(ivec2(fx, fy), ivec2(0), atlasSize - 1);
      if (isTexel(p)) { texel = p; return true; }
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          ivec2 q = p + ivec2(dx, dy);
          if (q.x < 0 || q.y < 0 || q.x >= atlasSize.x || q.y >= atlasSize.y) continue;
          if (isTexel(q)) { texel = q; return true; }
        }
      }
      return false;
    }

    // LafortuneLobe (engine/brdf/lafortune.h), per channel.
    vec3 LafortuneLobe(vec3 wi, vec3 wo, vec3 cx, vec3 cy, vec3 cz, vec3 n) {
      vec3 base = cx * (wi.x * wo.x) + cy * (wi.y * wo.y) + cz * (wi.z * wo.z);
      vec3 value;
      for (int c = 0; c < 3; ++c) {
        value[c] = base[c] <= kPowBaseMin ? 0.0 : min(pow(base[c], n[c]), kMaxLobeValue);
      }
      return value;
    }

    vec3 linearToSrgb(vec3 x) {
      x = clamp(x, 0.0, 1.0);
      return mix(12.92 * x, 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, x));
    }

    void main() {
      vec3 black = vec3(0.0);
      outColor = vec4(black, 1.0);
      vec3 p = vPos;
      vec3 wo = normalize(cameraPos - p);
      // Geometric normal of the triangle, facing the viewer on front faces.
      vec3 ng = normalize(cross(dFdx(vPos), dFdy(vPos)));
      if (dot(ng, wo) < 0.0) ng = -ng;
      if (!gl_FrontFacing) return;  // back face of an open mesh: black
      vec3 ns = normalize(vNormal);
      vec3 wi;
      vec3 irradiancePerCos = intensity;
      if (lightType == 0) {
        vec3 toLight = lightPos - p;
        float dist = length(toLight);
        wi = toLight / dist;
        irradiancePerCos /= dist * dist;
      } else {
        wi = normalize(lightDir);
      }
      float cosI = dot(ns, wi);
      if (cosI <= 0.0 || dot(ng, wi) <= 0.0) return;
      ivec2 texel;
      if (!texelOfHit(vUv, texel)) return;
      vec3 tangent = texelFetch(tangentTex, texel, 0).xyz;
      vec3 t = tangent - ns * dot(ns, tangent);
      if (dot(t, t) < 1e-12) {  // tangent parallel to the normal: any orthogonal unit vector
        t = abs(ns.x) > abs(ns.z) ? vec3(-ns.y, ns.x, 0.0) : vec3(0.0, -ns.z, ns.y);
      }
      t = normalize(t);
      vec3 b = cross(ns, t);
      vec3 wiLocal = vec3(dot(t, wi), dot(b, wi), cosI);
      vec3 woLocal = vec3(dot(t, wo), dot(b, wo), dot(ns, wo));
      if (woLocal.z <= 0.0) return;  // shading normal turned away from the viewer
      vec3 f = texelFetch(rhoTex, texel, 0).rgb * kInvPi;
${lobeSum(numLobes)}
      vec3 radiance = f * irradiancePerCos * cosI;
      outColor = vec4(linearToSrgb(radiance * exposure * displayScale), 1.0);
    }`;
  }

  function floatTexture(base64) {
    const tex = new THREE.DataTexture(decodeFloats(base64), data.atlas.width, data.atlas.height,
                                      THREE.RGBAFormat, THREE.FloatType);
    tex.magFilter = THREE.NearestFilter;
    tex.minFilter = THREE.NearestFilter;
    tex.generateMipmaps = false;
    tex.flipY = false;
    tex.needsUpdate = true;
    return tex;
  }

  const params = new URLSearchParams(window.location.search);
  const testView = params.has('test') ? parseInt(params.get('test'), 10) : -1;

  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(decodeFloats(data.mesh.position), 3));
  geometry.setAttribute('normal', new THREE.BufferAttribute(decodeFloats(data.mesh.normal), 3));
  geometry.setAttribute('uv', new THREE.BufferAttribute(decodeFloats(data.mesh.uv), 2));

  const lobeTextures = data.atlas.lobes.map(floatTexture);
  if (lobeTextures.length === 0) lobeTextures.push(floatTexture(data.atlas.rho));  // unused slot
  const uniforms = {
    rhoTex: {value: floatTexture(data.atlas.rho)},
    tangentTex: {value: floatTexture(data.atlas.tangent)},
    lobeTex: {value: lobeTextures},
    atlasSize: {value: new THREE.Vector2(data.atlas.width, data.atlas.height)},
    camFromObject: {value: new THREE.Matrix4()},
    intrinsics: {value: new THREE.Vector4()},
    imageSize: {value: new THREE.Vector2()},
    cameraPos: {value: new THREE.Vector3()},
    lightType: {value: 0},
    lightPos: {value: new THREE.Vector3()},
    lightDir: {value: new THREE.Vector3()},
    intensity: {value: new THREE.Vector3()},
    exposure: {value: 1},
    displayScale: {value: 1},
  };
  const material = new THREE.RawShaderMaterial({
    glslVersion: THREE.GLSL3,
    vertexShader: vertexShader,
    fragmentShader: fragmentShader(data.atlas.numLobes),
    uniforms: uniforms,
    side: THREE.DoubleSide,
  });
  const scene = new THREE.Scene();
  const mesh = new THREE.Mesh(geometry, material);
  mesh.frustumCulled = false;  // the vertex shader projects; three's culling knows nothing of it
  scene.add(mesh);
  const camera = new THREE.Camera();  // unused by the raw shader, required by render()

  const canvas = document.getElementById('render');
  const renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: false,
                                            preserveDrawingBuffer: true});
  renderer.setPixelRatio(1);
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;  // the shader writes sRGB itself
  renderer.setClearColor(0x000000, 1);
  let shaderError = false;
  renderer.debug.onShaderError = (gl, program, vertex, fragment) => {
    shaderError = true;
    console.error('reflcap viewer: shader error: ' + gl.getShaderInfoLog(fragment) +
                  gl.getShaderInfoLog(vertex));
  };

  // Interactive state: the held-out view, an orbit of the object about its centre, and the light
  // turned about the vertical axis / raised from the view's light.
  // The URL may set them (radians): index.html?test=0&yaw=0.5&lightYaw=1.
  const state = {view: Math.max(0, testView), yaw: 0, pitch: 0, lightYaw: 0, lightPitch: 0};
  for (const key of ['yaw', 'pitch', 'lightYaw', 'lightPitch']) {
    const value = parseFloat(params.get(key));
    if (Number.isFinite(value)) state[key] = value;
  }

  function rotationAbout(axis, angle) {
    return new THREE.Matrix4().makeRotationAxis(axis.clone().normalize(), angle);
  }

  function render() {
    const view = data.views[state.view];
    canvas.width = view.width;
    canvas.height = view.height;
    renderer.setSize(view.width, view.height, false);
    const camFromObject = new THREE.Matrix4().fromArray(view.camFromObject).transpose();
    const centre = new THREE.Vector3().fromArray(data.mesh.centre);
    const up = new THREE.Vector3().fromArray(data.mesh.up);
    // Orbit: turn the object about its centre (yaw about `up`, pitch about the camera's x axis).
    const camRot = new THREE.Matrix3().setFromMatrix4(camFromObject);
    const camX = new THREE.Vector3(1, 0, 0).applyMatrix3(camRot.clone().transpose());
    const orbit = new THREE.Matrix4().makeTranslation(centre.x, centre.y, centre.z)
        .multiply(rotationAbout(camX, state.pitch)).multiply(rotationAbout(up, state.yaw))
        .multiply(new THREE.Matrix4().makeTranslation(-centre.x, -centre.y, -centre.z));
    const m = camFromObject.clone().multiply(orbit);
    uniforms.camFromObject.value.copy(m);
    uniforms.cameraPos.value.set(0, 0, 0).applyMatrix4(m.clone().invert());
    uniforms.intrinsics.value.fromArray(view.intrinsics);
    uniforms.imageSize.value.set(view.width, view.height);
    const light = view.light;
    uniforms.lightType.value = light.type === 'point' ? 0 : 1;
    const lightTurn = rotationAbout(up, state.lightYaw);
    const lightAxis = new THREE.Vector3().fromArray(light.position || light.direction)
        .sub(light.type === 'point' ? centre : new THREE.Vector3()).cross(up);
    if (lightAxis.lengthSq() > 0) lightTurn.multiply(rotationAbout(lightAxis, state.lightPitch));
    if (light.type === 'point') {
      uniforms.lightPos.value.fromArray(light.position).sub(centre).applyMatrix4(lightTurn)
          .add(centre);
    } else {
      uniforms.lightDir.value.fromArray(light.direction).applyMatrix4(lightTurn);
    }
    uniforms.intensity.value.fromArray(light.intensity);
    uniforms.exposure.value = view.exposure;
    uniforms.displayScale.value = view.displayScale * state.brightness;
    renderer.render(scene, camera);
    const photo = document.getElementById('photo');
    if (photo) {
      photo.src = 'data:image/png;base64,' + view.photo;
      photo.width = view.width;
      photo.height = view.height;
      document.getElementById('caption').textContent =
          view.file + ' (camera ' + view.camera + ', light ' + light.id + ', turntable ' +
          view.turntableDeg + '°)' + (state.yaw || state.pitch ? ' — orbiting: the photograph ' +
          'shows the held-out view' : '');
    }
  }

  state.brightness = 1;
  if (testView < 0) {
    const select = document.getElementById('view');
    data.views.forEach((v, i) => {
      const option = document.createElement('option');
      option.value = i;
      option.textContent = v.file;
      select.appendChild(option);
    });
    select.addEventListener('change', () => {
      state.view = parseInt(select.value, 10);
      state.yaw = state.pitch = state.lightYaw = state.lightPitch = 0;
      render();
    });
    document.getElementById('reset').addEventListener('click', () => {
      state.yaw = state.pitch = state.lightYaw = state.lightPitch = 0;
      render();
    });
    document.getElementById('brightness').addEventListener('input', (e) => {
      state.brightness = Math.pow(2, parseFloat(e.target.value));
      render();
    });
    // Drag: orbit; shift-drag: move the light.
    let last = null;
    canvas.addEventListener('pointerdown', (e) => { last = e; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener('pointerup', () => { last = null; });
    canvas.addEventListener('pointermove', (e) => {
      if (!last) return;
      const dx = (e.clientX - last.clientX) * 0.01, dy = (e.clientY - last.clientY) * 0.01;
      if (e.shiftKey) {
        state.lightYaw += dx;
        state.lightPitch += dy;
      } else {
        state.yaw += dx;
        state.pitch += dy;
      }
      last = e;
      render();
    });
  } else {
    document.body.className = 'test';
  }
  render();
  document.title = shaderError ? 'shader error' : 'rendered';
})();
