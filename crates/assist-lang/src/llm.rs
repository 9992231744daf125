//! Optional LLM provider: an OpenAI-compatible chat-completions endpoint turns an
//! instruction into action JSON (as the paper asks GPT-4 to), and the answer is validated
//! exactly like the parser's output. Configured by environment: `ASSIST_LLM_URL` (base URL,
//! e.g. `http://localhost:8080/v1`), `ASSIST_LLM_MODEL`, optional `ASSIST_LLM_API_KEY`.

use std::collections::BTreeSet;
use std::time::Duration;

use assist_core::action::describe_nodes;
use assist_core::{Action, Scene, SceneSource};

use crate::LangError;

#[derive(Debug, Clone)]
pub struct LlmProvider {
    /// Base URL; `/chat/completions` is appended.
    pub url: String,
    pub model: String,
    pub api_key: Option<String>,
    pub timeout: Duration,
}

impl LlmProvider {
    /// The provider set by `ASSIST_LLM_URL` / `ASSIST_LLM_MODEL` / `ASSIST_LLM_API_KEY`, if any.
    pub fn from_env() -> Option<Self> {
        let url = std::env::var("ASSIST_LLM_URL")
            .ok()
            .filter(|u| !u.is_empty())?;
        Some(LlmProvider {
            url,
            model: std::env::var("ASSIST_LLM_MODEL").unwrap_or_else(|_| "gpt-4o-mini".into()),
            api_key: std::env::var("ASSIST_LLM_API_KEY")
                .ok()
                .filter(|k| !k.is_empty()),
            timeout: Duration::from_secs(60),
        })
    }

    /// The system prompt: the action schema and the scene's objects.
    pub fn prompt(scene: &Scene) -> String {
        format!(
            "You turn an instruction about a 3D scene into a JSON array of actions, nothing else. \
Each action is {{\"instance_id\": N, \"operation\": OP, \"config\": {{...}}}}. Operations and config: \
select {{}}; delete {{}}; translate {{\"axis\": \"x\"|\"y\"|\"z\"|\"-x\"..., \"distance\": d, \"unit\": \"m\"|\"cm\"|\"mm\"}} or {{\"vector\": [dx,dy,dz], \"unit\": ...}}; \
rotate {{\"axis\": ..., \"angle\": a, \"unit\": \"deg\"|\"rad\"}}; scale {{\"factor\": f}} (optionally \"axis\"); \
replicate {{}} or {{\"vector\": [...], \"unit\": ...}}; add {{\"scene\": PATH, \"node\": id or label}} with instance_id 0; \
swap {{\"with\": id}}. The world up axis is {:?}; units are metres unless given. Objects (id \"label\"): {}.",
            scene.up.to_array(),
            describe_nodes(scene)
        )
    }

    /// Asks the endpoint and validates its answer against `scene`.
    pub fn parse(
        &self,
        text: &str,
        scene: &Scene,
        sources: &mut dyn SceneSource,
    ) -> Result<Vec<Action>, LangError> {
        let body = serde_json::json!({
            "model": self.model,
            "temperature": 0,
            "messages": [
                {"role": "system", "content": Self::prompt(scene)},
                {"role": "user", "content": text},
            ],
        });
        let url = format!("{}/chat/completions", self.url.trim_end_matches('/'));
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .timeout_global(Some(self.timeout))
            .http_status_as_error(false)
            .build()
            .into();
        let mut req = agent.post(&url).header("Content-Type", "application/json");
        if let Some(k) = &self.api_key {
            req = req.header("Authorization", &format!("Bearer {k}"));
        }
        let mut resp = req
            .send(body.to_string())
            .map_err(|e| LangError::Llm(format!("{url}: {e}")))?;
        let status = resp.status();
        let text_body = resp
            .body_mut()
            .read_to_string()
            .map_err(|e| LangError::Llm(format!("{url}: reading the answer: {e}")))?;
        if !status.is_success() {
            return Err(LangError::Llm(format!(
                "{url}: HTTP {status}: {}",
                text_body.chars().take(300).collect::<String>()
            )));
        }
        let v: serde_json::Value = serde_json::from_str(&text_body)
            .map_err(|e| LangError::Llm(format!("{url}: not JSON: {e}")))?;
        let content = v
            .pointer("/choices/0/message/content")
            .and_then(|c| c.as_str())
            .ok_or_else(|| {
                LangError::Llm(format!(
                    "{url}: no choices[0].message.content in the answer"
                ))
            })?;
        let actions = actions_from_answer(content)?;
        validate_all(&actions, scene, sources)?;
        Ok(actions)
    }
}

/// Reads actions from a model's answer: a JSON array or one object, optionally inside a
/// ``` fence.
pub fn actions_from_answer(content: &str) -> Result<Vec<Action>, LangError> {
    let t = content.trim();
    let t = t
        .strip_prefix("```json")
        .or_else(|| t.strip_prefix("```"))
        .map(|r| r.trim_end().trim_end_matches("```"))
        .unwrap_or(t)
        .trim();
    let bad = |e: serde_json::Error| {
        LangError::Llm(format!(
            "the answer is not action JSON ({e}): {}",
            t.chars().take(200).collect::<String>()
        ))
    };
    if t.starts_with('[') {
        serde_json::from_str(t).map_err(bad)
    } else {
        serde_json::from_str::<Action>(t)
            .map(|a| vec![a])
            .map_err(bad)
    }
}

/// Validates actions in order against `scene` (as the parser's output is).
pub fn validate_all(
    actions: &[Action],
    scene: &Scene,
    sources: &mut dyn SceneSource,
) -> Result<(), LangError> {
    let mut s = scene.clone();
    for (i, a) in actions.iter().enumerate() {
        let clause = format!("action {} of the answer", i + 1);
        let e = a
            .validate(&s, sources, &BTreeSet::new())
            .map_err(|source| LangError::Action {
                clause: clause.clone(),
                source,
            })?;
        assist_core::edit::apply(&mut s, &e)
            .map_err(|source| LangError::Action { clause, source })?;
    }
    Ok(())
}
