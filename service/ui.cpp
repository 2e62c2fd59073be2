#include "ui.hpp"

#include <fstream>
#include <sstream>

#include "ui_assets.hpp"

namespace spokemesh::service {

std::shared_ptr<const UiAssets> UiAssets::load(const std::string& three_dir) {
  auto ui = std::make_shared<UiAssets>();
  for (const EmbeddedAsset& a : kEmbeddedUi) {
    ui->by_path_["/ui/" + std::string(a.name)] = UiAsset{std::string(a.content_type), a.body};
    ui->embedded_bytes_ += a.body.size();
  }
  // The two pages under their own short paths.
  ui->by_path_["/"] = ui->by_path_.at("/ui/index.html");
  ui->by_path_["/docs"] = ui->by_path_.at("/ui/docs.html");
  // Debian's libjs-three (r111): the UMD build and the OrbitControls that attach to
  // the global THREE.
  const std::pair<const char*, const char*> system_files[] = {
      {"/ui/three.min.js", "/build/three.min.js"}, {"/ui/OrbitControls.js", "/examples/js/controls/OrbitControls.js"}};
  for (const auto& [path, file] : system_files) {
    std::ifstream in(three_dir + file, std::ios::binary);
    std::ostringstream text;
    if (in) text << in.rdbuf();
    if (!in || text.str().empty()) {
      ui->missing_ += (ui->missing_.empty() ? "" : ", ") + three_dir + file;
      continue;
    }
    ui->owned_.push_back(std::make_unique<std::string>(text.str()));
    ui->by_path_[path] = UiAsset{"text/javascript; charset=utf-8", *ui->owned_.back()};
  }
  return ui;
}

const UiAsset* UiAssets::find(std::string_view path) const {
  const auto it = by_path_.find(path);
  return it == by_path_.end() ? nullptr : &it->second;
}

const std::vector<std::pair<std::string, std::string>>& UiAssets::security_headers() {
  // 'self' only: no inline script or style, no eval, no frames; fetch/XHR only to this
  // origin; images only from here or data: URLs (the canvas' own snapshots).
  static const std::vector<std::pair<std::string, std::string>> headers = {
      {"Content-Security-Policy",
       "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"},
      {"X-Content-Type-Options", "nosniff"},
      {"Referrer-Policy", "no-referrer"},
      {"X-Frame-Options", "DENY"},
      {"Cache-Control", "no-cache"}};
  return headers;
}

}  // namespace spokemesh::service
