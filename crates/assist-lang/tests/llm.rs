//! The optional LLM provider against a local fake OpenAI-compatible server: its answer is
//! parsed and validated exactly like the built-in parser's output.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::sync::mpsc;

use assist_core::action::NoSources;
use assist_core::{DMat3, DVec3, Obb, Scene, SceneNode};
use assist_lang::LangError;
use assist_lang::LlmProvider;

fn scene() -> Scene {
    let n = |id: u16, label: &str| {
        SceneNode::from_obb(
            id,
            label,
            &format!("f{id}"),
            &Obb::new(
                DVec3::new(id as f64, 0.0, 0.0),
                DVec3::splat(0.05),
                DMat3::IDENTITY,
            ),
        )
    };
    Scene::with_nodes(
        vec![
            n(0, "background"),
            n(1, "yellow rubber duck"),
            n(3, "red ceramic mug"),
        ],
        DVec3::Z,
    )
}

/// Serves one request with `status` and a chat-completions body whose message content is
/// `content`; sends the request body it received back through the channel.
fn serve_once(status: u16, content: &str) -> (String, mpsc::Receiver<String>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let body =
        serde_json::json!({"choices": [{"message": {"role": "assistant", "content": content}}]})
            .to_string();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().unwrap();
        let mut reader = BufReader::new(stream.try_clone().unwrap());
        let mut len = 0usize;
        loop {
            let mut line = String::new();
            reader.read_line(&mut line).unwrap();
            if line == "\r\n" || line.is_empty() {
                break;
            }
            if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                len = v.trim().parse().unwrap();
            }
        }
        let mut req = vec![0u8; len];
        reader.read_exact(&mut req).unwrap();
        tx.send(String::from_utf8(req).unwrap()).unwrap();
        let reply = format!(
            "HTTP/1.1 {status} X\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        );
        stream.write_all(reply.as_bytes()).unwrap();
    });
    (format!("http://{addr}/v1"), rx)
}

fn provider(url: String) -> LlmProvider {
    LlmProvider {
        url,
        model: "fake".into(),
        api_key: Some("k".into()),
        timeout: std::time::Duration::from_secs(10),
    }
}

#[test]
fn answers_are_parsed_and_validated() {
    let answer = "```json\n[{\"instance_id\": 3, \"operation\": \"translate\", \"config\": {\"axis\": \"x\", \"distance\": 10, \"unit\": \"cm\"}},\n {\"instance_id\": 1, \"operation\": \"delete\", \"config\": {}}]\n```";
    let (url, rx) = serve_once(200, answer);
    let actions = provider(url)
        .parse(
            "move the mug 10 cm along x and delete the duck",
            &scene(),
            &mut NoSources,
        )
        .unwrap();
    assert_eq!(actions.len(), 2);
    assert_eq!(actions[0].instance_id, 3);
    assert_eq!(actions[0].config.distance, Some(10.0));
    let req: serde_json::Value = serde_json::from_str(&rx.recv().unwrap()).unwrap();
    assert_eq!(req["model"], "fake");
    let system = req["messages"][0]["content"].as_str().unwrap();
    assert!(system.contains("3 \"red ceramic mug\""), "{system}");
    assert_eq!(
        req["messages"][1]["content"],
        "move the mug 10 cm along x and delete the duck"
    );
}

#[test]
fn invalid_answers_are_errors() {
    // An id the scene does not have.
    let (url, _rx) = serve_once(
        200,
        r#"[{"instance_id": 42, "operation": "delete", "config": {}}]"#,
    );
    let e = provider(url)
        .parse("delete the chair", &scene(), &mut NoSources)
        .unwrap_err();
    assert!(
        e.to_string().contains("instance_id 42: no such node"),
        "{e}"
    );
    // An impossible value.
    let (url, _rx) = serve_once(
        200,
        r#"{"instance_id": 3, "operation": "scale", "config": {"factor": 0}}"#,
    );
    let e = provider(url)
        .parse("scale the mug by 0", &scene(), &mut NoSources)
        .unwrap_err();
    assert!(e.to_string().contains("factor > 0"), "{e}");
    // Prose instead of JSON.
    let (url, _rx) = serve_once(200, "Sure! I moved the mug for you.");
    let e = provider(url)
        .parse("move the mug", &scene(), &mut NoSources)
        .unwrap_err();
    assert!(
        matches!(e, LangError::Llm(_)) && e.to_string().contains("not action JSON"),
        "{e}"
    );
    // An HTTP error.
    let (url, _rx) = serve_once(500, "x");
    let e = provider(url)
        .parse("move the mug", &scene(), &mut NoSources)
        .unwrap_err();
    assert!(e.to_string().contains("HTTP 500"), "{e}");
}
