//! The HTML page: one template with the scene JSON and the viewer script inlined, so the static
//! page opens from `file://` with no network.

use crate::scene::Scene;

const TEMPLATE: &str = include_str!("assets/viewer.html");
const SCRIPT: &str = include_str!("assets/viewer.js");

/// The page for a scene.
pub fn render(scene: &Scene) -> String {
    // `<` only occurs inside JSON strings, where \u003c means the same and cannot close the tag.
    let json = serde_json::to_string(scene).unwrap_or_else(|_| "{}".into()).replace('<', "\\u003c");
    let title = scene.title.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;");
    TEMPLATE.replacen("__TITLE__", &title, 1).replacen("__SCENE__", &json, 1).replacen("__SCRIPT__", SCRIPT, 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ColorBy;

    #[test]
    fn scene_cannot_close_its_script_tag() {
        let scene = Scene { title: "a </script> <b>".into(), mode: "view", color: ColorBy::Height, frames: vec![] };
        let html = render(&scene);
        assert!(!html.contains("a </script>"));
        assert!(html.contains("a &lt;/script&gt;"));
        assert_eq!(html.matches("</script>").count(), 2, "the scene's and the viewer's script tags only");
        assert!(!SCRIPT.contains("</script"));
    }
}
