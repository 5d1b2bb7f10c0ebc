//! Every shader parses and validates with naga: the WGSL modules as they are, the GLSL bodies
//! (common to GLSL ES 3.00 and 4.50) under 4.50 declarations of the same names, since naga's
//! GLSL front end reads Vulkan GLSL 4.40+ only.

use naga::valid::{Capabilities, ValidationFlags, Validator};
use prt_shaders::CoefficientStorage;

const RANKS: [usize; 4] = [1, 3, 4, 8];

fn validate(module: &naga::Module, what: &str) {
    Validator::new(ValidationFlags::all(), Capabilities::default())
        .validate(module)
        .unwrap_or_else(|e| panic!("{what} does not validate: {e:?}"));
}

fn parse_wgsl(source: &str, what: &str) -> naga::Module {
    naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{what} does not parse:\n{}", e.emit_to_string(source)))
}

fn parse_glsl(source: &str, stage: naga::ShaderStage, what: &str) -> naga::Module {
    naga::front::glsl::Frontend::default()
        .parse(&naga::front::glsl::Options::from(stage), source)
        .unwrap_or_else(|e| panic!("{what} does not parse:\n{}", e.emit_to_string(source)))
}

/// A fragment entry point that uses the reconstruction and the irradiance.
const WGSL_FRAGMENT: &str = "
@fragment
fn fs_main(@location(0) world: vec3<f32>, @location(1) normal: vec3<f32>) -> @location(0) vec4<f32> {
    let sh = mbd_incident_radiance(world);
    return vec4<f32>(mbd_irradiance(sh, normal), 1.0);
}
";

#[test]
fn the_wgsl_modules_validate() {
    for rank in RANKS {
        for layout in [CoefficientStorage::Dense, CoefficientStorage::Bricks] {
            let reconstruct = prt_shaders::wgsl_reconstruct_for(rank, layout) + WGSL_FRAGMENT;
            let what = format!("reconstruct.wgsl rank {rank}, {layout:?}");
            let module = parse_wgsl(&reconstruct, &what);
            validate(&module, &what);
            assert!(module.entry_points.iter().any(|e| e.name == "fs_main"));
        }

        let light = prt_shaders::wgsl_light(rank);
        let module = parse_wgsl(&light, &format!("light.wgsl rank {rank}"));
        validate(&module, &format!("light.wgsl rank {rank}"));
        let entry = module
            .entry_points
            .iter()
            .find(|e| e.name == "mbd_light_main")
            .expect("the lighting entry point");
        assert_eq!(entry.stage, naga::ShaderStage::Compute);
        assert_eq!(entry.workgroup_size, [4, 4, 4]);
    }
}

/// Vulkan GLSL 4.50 declarations of the names reconstruct.glsl reads (the test's stand-in
/// for reconstruct_es.glsl).
const GLSL_RECONSTRUCT_450: &str = "
layout(std140, set = 0, binding = 0) uniform MbdReconstruction {
    MbdGrid u_mbd_coefficients;
    MbdGrid u_mbd_lit;
    vec4 u_mbd_coefficient_scale[MBD_COEFFICIENT_GROUPS];
    vec4 u_mbd_coefficient_bias[MBD_COEFFICIENT_GROUPS];
};
layout(set = 0, binding = 1) uniform texture3D u_mbd_coefficient_texture;
layout(set = 0, binding = 2) uniform texture3D u_mbd_lit_texture;
layout(set = 0, binding = 3) uniform sampler u_mbd_linear_clamp;
#define MBD_SAMPLE3D(t, uvw) textureLod(sampler3D(t, u_mbd_linear_clamp), uvw, 0.0)
";

/// The same for coefficients_bricks.glsl (the stand-in for bricks_es.glsl).
const GLSL_BRICKS_450: &str = "
layout(std140, set = 1, binding = 0) uniform MbdBrickLayout {
    MbdBricks u_mbd_bricks;
};
layout(set = 1, binding = 1) uniform texture3D u_mbd_coefficient_indirection;
#define MBD_FETCH_INDIRECTION(t, p) texelFetch(sampler3D(t, u_mbd_linear_clamp), p, 0)
";

const GLSL_FRAGMENT_450: &str = "
layout(location = 0) in vec3 v_world;
layout(location = 1) in vec3 v_normal;
layout(location = 0) out vec4 o_color;
void main() {
    vec4 sh[7];
    mbd_incident_radiance(v_world, sh);
    o_color = vec4(mbd_irradiance(sh, v_normal), 1.0);
}
";

/// The same for light.glsl.
const GLSL_LIGHT_450: &str = "
layout(std140, set = 0, binding = 0) uniform MbdLight {
    MbdGrid u_mbd_basis;
    MbdGrid u_mbd_lit;
    vec4 u_mbd_sky[7];
    int u_mbd_slice;
};
layout(set = 0, binding = 1) uniform texture3D u_mbd_basis_texture;
layout(set = 0, binding = 2) uniform texture2D u_mbd_basis_ranges;
layout(set = 0, binding = 3) uniform sampler u_mbd_nearest;
layout(location = 0) out vec4 mbd_lit;
#define MBD_FETCH3D(t, p) texelFetch(sampler3D(t, u_mbd_nearest), p, 0)
#define MBD_FETCH2D(t, p) texelFetch(sampler2D(t, u_mbd_nearest), p, 0)
";

fn glsl_450(rank: usize, parts: &[&str]) -> String {
    let mut source = format!("#version 450 core\n#define RANK {rank}\n");
    for part in parts {
        source.push_str(part);
        source.push('\n');
    }
    source
}

#[test]
fn the_glsl_bodies_validate() {
    use prt_shaders::glsl;
    for rank in RANKS {
        for (layout, parts) in [
            (
                "dense",
                [
                    glsl::COMMON,
                    GLSL_RECONSTRUCT_450,
                    "",
                    glsl::COEFFICIENTS_DENSE,
                ],
            ),
            (
                "bricks",
                [
                    glsl::COMMON,
                    GLSL_RECONSTRUCT_450,
                    GLSL_BRICKS_450,
                    glsl::COEFFICIENTS_BRICKS,
                ],
            ),
        ] {
            let mut parts = parts.to_vec();
            parts.extend([glsl::RECONSTRUCT, GLSL_FRAGMENT_450]);
            let reconstruct = glsl_450(rank, &parts);
            let what = format!("reconstruct.glsl rank {rank}, {layout}");
            validate(
                &parse_glsl(&reconstruct, naga::ShaderStage::Fragment, &what),
                &what,
            );
        }
        let light = glsl_450(rank, &[glsl::COMMON, GLSL_LIGHT_450, glsl::LIGHT]);
        let what = format!("light.glsl rank {rank}");
        validate(
            &parse_glsl(&light, naga::ShaderStage::Fragment, &what),
            &what,
        );
    }
}

/// The GLSL ES sources start with their version line and define what the bodies read.
#[test]
fn the_glsl_es_sources_are_complete() {
    let reconstruct = prt_shaders::glsl_reconstruct(8);
    assert!(reconstruct.starts_with("#version 300 es\n"));
    let light = prt_shaders::glsl_light(3);
    assert!(light.starts_with("#version 300 es\n"));
    for name in [
        "u_mbd_coefficients",
        "u_mbd_lit",
        "u_mbd_coefficient_scale",
        "u_mbd_coefficient_bias",
        "u_mbd_coefficient_texture",
        "u_mbd_lit_texture",
        "MBD_SAMPLE3D",
    ] {
        assert!(
            prt_shaders::glsl::RECONSTRUCT_ES.contains(name),
            "reconstruct_es.glsl declares {name}"
        );
        assert!(GLSL_RECONSTRUCT_450.contains(name));
    }
    for name in [
        "u_mbd_bricks",
        "u_mbd_coefficient_indirection",
        "MBD_FETCH_INDIRECTION",
    ] {
        assert!(
            prt_shaders::glsl::BRICKS_ES.contains(name),
            "bricks_es.glsl declares {name}"
        );
        assert!(GLSL_BRICKS_450.contains(name));
    }
    let bricks = prt_shaders::glsl_reconstruct_for(8, CoefficientStorage::Bricks);
    assert!(
        bricks.starts_with("#version 300 es\n") && bricks.contains("u_mbd_coefficient_indirection")
    );
    for name in [
        "u_mbd_basis",
        "u_mbd_lit",
        "u_mbd_sky",
        "u_mbd_slice",
        "u_mbd_basis_texture",
        "u_mbd_basis_ranges",
        "mbd_lit",
        "MBD_FETCH3D",
        "MBD_FETCH2D",
    ] {
        assert!(
            prt_shaders::glsl::LIGHT_ES.contains(name),
            "light_es.glsl declares {name}"
        );
        assert!(GLSL_LIGHT_450.contains(name));
    }
}

/// The complete GLSL ES 3.00 sources compile with the Khronos reference compiler
/// (`glslangValidator`, Debian package glslang-tools); ignored where it is not installed, unless
/// `PRT_REQUIRE_GLSLANG=1` (see build.rs).
#[test]
#[cfg_attr(
    prt_skip_glslang,
    ignore = "glslangValidator not installed (apt-get install glslang-tools)"
)]
fn the_glsl_es_sources_compile_with_glslang() {
    let main = "
in vec3 v_world;
in vec3 v_normal;
out vec4 o_color;
void main() {
    vec4 sh[7];
    mbd_incident_radiance(v_world, sh);
    o_color = vec4(mbd_irradiance(sh, v_normal), 1.0);
}
";
    let dir = std::env::temp_dir().join(format!("prt-shaders-glslang-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp folder");
    for rank in RANKS {
        for (name, source) in [
            ("reconstruct", prt_shaders::glsl_reconstruct(rank) + main),
            (
                "reconstruct_bricks",
                prt_shaders::glsl_reconstruct_for(rank, CoefficientStorage::Bricks) + main,
            ),
            ("light", prt_shaders::glsl_light(rank)),
        ] {
            let path = dir.join(format!("{name}_{rank}.frag"));
            std::fs::write(&path, &source).expect("write shader");
            let out = std::process::Command::new("glslangValidator")
                .arg(&path)
                .output()
                .expect("run glslangValidator");
            assert!(
                out.status.success(),
                "{name} rank {rank}:\n{}",
                String::from_utf8_lossy(&out.stdout)
            );
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// The lobes `prt lightmap --basis sg:N` writes (a Fibonacci spiral over the upper
/// hemisphere, sharpness N ln 2), rebuilt here so that the test needs no prt-lightmap.
fn lightmap_lobes(n: usize) -> (Vec<[f32; 3]>, f32) {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let axes = (0..n)
        .map(|i| {
            let y = 1.0 - (i as f64 + 0.5) / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f64;
            [(r * phi.cos()) as f32, y as f32, (r * phi.sin()) as f32]
        })
        .collect();
    (axes, (n as f64 * std::f64::consts::LN_2) as f32)
}

const LOBES: [usize; 4] = [1, 4, 9, 12];

const WGSL_LIGHTMAP_SG_FRAGMENT: &str = "
@fragment
fn fs_main(@location(0) normal: vec3<f32>, @location(1) view: vec3<f32>, @location(2) c0: vec3<f32>) -> @location(0) vec4<f32> {
    var c: array<vec3<f32>, LM_SG_LOBES>;
    for (var i = 0u; i < LM_SG_LOBES; i++) { c[i] = c0 * f32(i + 1u); }
    let frame = lm_tangent_frame(normalize(normal));
    let v = lm_to_tangent(frame, normalize(view));
    let n = vec3<f32>(0.0, 1.0, 0.0);
    let rgb = lm_sg_diffuse(c, n) / 3.14159265 + lm_sg_specular(c, n, v, 0.5, vec3<f32>(0.04));
    return vec4<f32>(rgb, 1.0);
}
";

const WGSL_LIGHTMAP_SH_FRAGMENT: &str = "
@fragment
fn fs_main(@location(0) normal: vec3<f32>, @location(1) view: vec3<f32>, @location(2) c0: vec3<f32>) -> @location(0) vec4<f32> {
    var c: array<vec3<f32>, 9>;
    for (var i = 0u; i < 9u; i++) { c[i] = c0 * f32(i + 1u); }
    let frame = lm_tangent_frame(normalize(normal));
    let v = lm_to_tangent(frame, normalize(view));
    let n = vec3<f32>(0.0, 1.0, 0.0);
    let rgb = lm_sh_diffuse(c, n) / 3.14159265 + lm_sh_specular(c, n, v, 0.5, vec3<f32>(0.04));
    return vec4<f32>(rgb, 1.0);
}
";

#[test]
fn the_wgsl_lightmap_libraries_validate() {
    for n in LOBES {
        let (axes, sharpness) = lightmap_lobes(n);
        let source =
            prt_shaders::wgsl_lightmap_sg(&axes, sharpness).unwrap() + WGSL_LIGHTMAP_SG_FRAGMENT;
        let what = format!("lightmap_sg.wgsl, {n} lobes");
        validate(&parse_wgsl(&source, &what), &what);
    }
    let source = prt_shaders::wgsl_lightmap_sh() + WGSL_LIGHTMAP_SH_FRAGMENT;
    validate(&parse_wgsl(&source, "lightmap_sh.wgsl"), "lightmap_sh.wgsl");
}

/// Bad lobe sets are refused, not written into a shader.
#[test]
fn bad_sg_lobes_are_errors() {
    assert!(prt_shaders::wgsl_lightmap_sg(&[], 1.0).is_err());
    assert!(prt_shaders::wgsl_lightmap_sg(&[[0.0, 2.0, 0.0]], 1.0).is_err());
    assert!(prt_shaders::glsl_lightmap_sg(&[[0.0, f32::NAN, 0.0]], 1.0).is_err());
    assert!(prt_shaders::glsl_lightmap_sg(&[[0.0, 1.0, 0.0]], f32::INFINITY).is_err());
    assert!(prt_shaders::glsl_lightmap_sg(&[[0.0, 1.0, 0.0]], -1.0).is_err());
}

/// A fragment `main` for the GLSL lightmap libraries; `{C}` is the coefficient count.
fn glsl_lightmap_main(prefix: &str, count: &str, declarations: &str) -> String {
    format!(
        "{declarations}
void main() {{
    vec3 c[{count}];
    for (int i = 0; i < {count}; i++) {{ c[i] = v_c0 * float(i + 1); }}
    mat3 frame = lm_tangent_frame(normalize(v_normal));
    vec3 v = lm_to_tangent(frame, normalize(v_view));
    vec3 n = vec3(0.0, 1.0, 0.0);
    vec3 rgb = {prefix}_diffuse(c, n) / 3.14159265 + {prefix}_specular(c, n, v, 0.5, vec3(0.04));
    o_color = vec4(rgb, 1.0);
}}
"
    )
}

const GLSL_LIGHTMAP_IO_450: &str = "
layout(location = 0) in vec3 v_normal;
layout(location = 1) in vec3 v_view;
layout(location = 2) in vec3 v_c0;
layout(location = 0) out vec4 o_color;";

const GLSL_LIGHTMAP_IO_ES: &str = "
in vec3 v_normal;
in vec3 v_view;
in vec3 v_c0;
out vec4 o_color;";

#[test]
fn the_glsl_lightmap_bodies_validate() {
    for n in LOBES {
        let (axes, sharpness) = lightmap_lobes(n);
        let source = format!(
            "#version 450 core\n{}{}",
            prt_shaders::glsl_lightmap_sg_body(&axes, sharpness).unwrap(),
            glsl_lightmap_main("lm_sg", "LM_SG_LOBES", GLSL_LIGHTMAP_IO_450)
        );
        let what = format!("lightmap_sg.glsl, {n} lobes");
        validate(
            &parse_glsl(&source, naga::ShaderStage::Fragment, &what),
            &what,
        );
    }
    let source = format!(
        "#version 450 core\n{}{}{}",
        prt_shaders::glsl::LIGHTMAP_COMMON,
        prt_shaders::glsl::LIGHTMAP_SH,
        glsl_lightmap_main("lm_sh", "9", GLSL_LIGHTMAP_IO_450)
    );
    validate(
        &parse_glsl(&source, naga::ShaderStage::Fragment, "lightmap_sh.glsl"),
        "lightmap_sh.glsl",
    );
}

/// The complete GLSL ES 3.00 lightmap libraries compile with `glslangValidator` (ignored where
/// it is not installed, unless `PRT_REQUIRE_GLSLANG=1`).
#[test]
#[cfg_attr(
    prt_skip_glslang,
    ignore = "glslangValidator not installed (apt-get install glslang-tools)"
)]
fn the_glsl_es_lightmap_libraries_compile_with_glslang() {
    let dir = std::env::temp_dir().join(format!("prt-shaders-lightmap-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp folder");
    let mut sources = vec![(
        "lightmap_sh".to_string(),
        prt_shaders::glsl_lightmap_sh() + &glsl_lightmap_main("lm_sh", "9", GLSL_LIGHTMAP_IO_ES),
    )];
    for n in LOBES {
        let (axes, sharpness) = lightmap_lobes(n);
        sources.push((
            format!("lightmap_sg_{n}"),
            prt_shaders::glsl_lightmap_sg(&axes, sharpness).unwrap()
                + &glsl_lightmap_main("lm_sg", "LM_SG_LOBES", GLSL_LIGHTMAP_IO_ES),
        ));
    }
    for (name, source) in sources {
        assert!(source.starts_with("#version 300 es\n"));
        let path = dir.join(format!("{name}.frag"));
        std::fs::write(&path, &source).expect("write shader");
        let out = std::process::Command::new("glslangValidator")
            .arg(&path)
            .output()
            .expect("run glslangValidator");
        assert!(
            out.status.success(),
            "{name}:\n{}",
            String::from_utf8_lossy(&out.stdout)
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}
